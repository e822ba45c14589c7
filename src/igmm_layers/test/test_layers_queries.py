"""Layers, class hierarchies, queries, configuration, drawing geometry and scores (no ROS)."""
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from igmm_layers import ClassHierarchy, ClusterTable, LayerParams, LayerSet
from igmm_layers.errors import InvalidInputError, NotFittedError, UnknownNameError
from igmm_layers.params import LayerServerConfig
from igmm_layers.queries import alternate_classes, closest, count_observed, most_likely, pair_likelihood
from igmm_layers.sim.metrics import match_scores, ospa
from igmm_layers.visual import class_colour, ellipse
from robot_common.errors import ConfigError

CONFIG = Path(__file__).resolve().parent.parent / "config" / "igmm_layers.yaml"


def table(rows, region="r1"):
    """rows: (class, (x, y), variance, weight, support, times)."""
    return ClusterTable([r[0] for r in rows], [region] * len(rows), ["objects"] * len(rows),
                        np.array([r[1] for r in rows], float),
                        np.array([np.eye(2) * r[2] for r in rows]), np.array([r[3] for r in rows]),
                        np.array([r[4] for r in rows]), np.full(len(rows), 10),
                        np.array([min(r[5]) for r in rows]), np.array([max(r[5]) for r in rows]),
                        [sorted(r[5]) for r in rows])


def test_hierarchy_expands_nested_groups_and_refuses_cycles_and_unknown_names():
    h = ClassHierarchy({"furniture": ["chair", "table", "seating"], "seating": ["couch"]})
    assert h.expand("furniture") == {"chair", "table", "couch"}
    assert h.groups_of("couch") == ["furniture", "seating"]
    assert h.resolve("any", ["mug", "chair"]) == ["chair", "mug"]
    assert h.resolve("couch", []) == ["couch"]  # a class of the hierarchy, not seen yet
    with pytest.raises(UnknownNameError, match="unknown class 'spoon'.*classes: mug.*groups: furniture"):
        h.resolve("spoon", ["mug"])
    with pytest.raises(InvalidInputError, match="cycle"):
        ClassHierarchy({"a": ["b"], "b": ["a"]})
    with pytest.raises(InvalidInputError, match="must list class names"):
        ClassHierarchy({"a": "chair"})


def test_layer_set_learns_per_region_and_class_and_answers_groups():
    layers = LayerSet(hierarchy=ClassHierarchy({"furniture": ["chair", "table"]}),
                      defaults=LayerParams(v_min=1000))
    rng = np.random.default_rng(0)
    for region, offset in (("floor_1", 0.0), ("floor_2", 100.0)):
        layer = layers.layer(region, "objects", create=True)
        for name, spot in (("chair", (1.0, 1.0, 0.5)), ("table", (4.0, 1.0, 0.7)), ("mug", (4.0, 1.2, 0.9))):
            layer.observe(name, rng.normal(np.add(spot, offset), 0.05, (10, 3)))
    furniture = layers.table("furniture", "floor_1")
    assert sorted(furniture.class_names) == ["chair", "table"]
    assert len(layers.table("any", "")) == 6
    assert set(layers.table("chair", "").region_ids) == {"floor_1", "floor_2"}
    assert layers.table("chair", "floor_2").means[0] == pytest.approx([101.0, 101.0], abs=0.1)
    with pytest.raises(UnknownNameError, match="unknown region 'floor_9'"):
        layers.table("chair", "floor_9")
    with pytest.raises(UnknownNameError, match="unknown layer 'rooms'"):
        layers.table("chair", "floor_1", "rooms")
    with pytest.raises(InvalidInputError, match="confidences"):
        layers.layer("floor_1", "objects").observe("chair", [[1.0, 1.0]], confidences=[1.5])


def test_most_likely_and_closest():
    t = table([("chair", (0, 0), 0.1, 0.3, 5.0, [1]), ("chair", (5, 0), 0.1, 0.7, 12.0, [1])])
    assert most_likely(t) == 1
    assert closest(t, (1.0, 1.0, 0.0)) == (0, pytest.approx(math.sqrt(2)))
    with pytest.raises(NotFittedError):
        most_likely(table([]))
    with pytest.raises(InvalidInputError, match="finite"):
        closest(t, (float("nan"), 0.0))


def test_pair_likelihood_overlap_and_distance_weighted_by_hand():
    a = table([("mug", (0, 0), 0.1, 1.0, 5, [1])])
    b = table([("sink", (1, 0), 0.1, 0.5, 5, [1]), ("sink", (2, 0), 0.2, 0.5, 5, [1]),
               ("sink", (8, 0), 0.1, 0.0, 5, [1])])
    # overlap: sum w_a w_b N(mu_a; mu_b, C_a + C_b); variances add: 0.2 and 0.3
    overlap = 0.5 * math.exp(-0.5 * 1 / 0.2) / (2 * math.pi * 0.2) + \
        0.5 * math.exp(-0.5 * 4 / 0.3) / (2 * math.pi * 0.3)
    value, method, pairs = pair_likelihood(a, b, method="overlap")
    assert (method, pairs) == ("overlap", 2) and value == pytest.approx(overlap)
    # original: mean of N(mu_a; mu_b, C_b) weighted by exp(-d)
    p1, p2 = math.exp(-0.5 / 0.1) / (2 * math.pi * 0.1), math.exp(-0.5 * 4 / 0.2) / (2 * math.pi * 0.2)
    expected = (math.exp(-1) * p1 + math.exp(-2) * p2) / (math.exp(-1) + math.exp(-2))
    value, method, pairs = pair_likelihood(a, b, method="distance_weighted")
    assert method == "distance_weighted" and value == pytest.approx(expected)
    assert pair_likelihood(a, b) == (value, "distance_weighted", 2)  # the default: the report's definition
    assert pair_likelihood(a, b, max_distance=10.0)[2] == 3
    other_region = table([("sink", (1, 0), 0.1, 1, 5, [1])], region="r2")
    assert pair_likelihood(a, other_region) == (0.0, "distance_weighted", 0)
    with pytest.raises(InvalidInputError, match="unknown method"):
        pair_likelihood(a, b, method="cosine")
    with pytest.raises(InvalidInputError, match="max_distance"):
        pair_likelihood(a, b, max_distance=-1)


def test_alternate_classes_ranks_the_nearest_class_first():
    tables = {"mug": table([("mug", (0, 0), 0.1, 1, 5, [1])]),
              "sink": table([("sink", (0.5, 0), 0.1, 1, 5, [1])]),
              "kettle": table([("kettle", (1.5, 0), 0.1, 1, 5, [1])]),
              "sofa": table([("sofa", (30, 0), 0.1, 1, 5, [1])])}
    ranked, method = alternate_classes(tables.__getitem__, "mug", sorted(tables))
    assert [name for name, _ in ranked] == ["sink", "kettle"] and method == "distance_weighted"


def test_count_observed_in_a_time_window_near_a_point():
    t = table([("chair", (0, 0), 0.1, 0.5, 5, [10, 20, 30]), ("chair", (1, 0), 0.1, 0.5, 5, [50]),
               ("table", (0, 1), 0.1, 1, 5, [15, 25]), ("chair", (9, 9), 0.1, 0.5, 5, [12])])
    near = count_observed(t, start=12, end=26, center=(0, 0), radius=2.0)
    assert near == {"chair": (1, 1), "table": (1, 2)}
    assert count_observed(t) == {"chair": (3, 5), "table": (1, 2)}
    assert count_observed(t, start=40) == {"chair": (1, 1)}
    with pytest.raises(InvalidInputError, match="starts after it ends"):
        count_observed(t, start=5, end=1)


def test_shipped_configuration_loads_and_bad_configurations_are_refused():
    params = yaml.safe_load(CONFIG.read_text())
    config = LayerServerConfig.from_params(params)
    assert config.layer_defaults.v_min == 100 and config.hierarchy.is_group("furniture")
    regional = LayerServerConfig.from_params({**params, "regions": [
        {"region_id": "floor_4", "kind": "objects", "observation_topic": "/floor_4/objects",
         "region_size": 40.0}]})
    assert regional.regions[("floor_4", "objects")].region_size == 40.0
    assert regional.regions[("floor_4", "objects")].v_min == 100  # rest from layer_defaults
    bad = [({"colour": 1}, "unknown parameter"),
           ({"layer_defaults": {"v_min": "lots"}}, "bad layer parameter"),
           ({"layer_defaults": {"novelty_constant": 2}}, "novelty_constant"),
           ({"regions": [{"kind": "objects"}]}, "without region_id"),
           ({"pair_method": "cosine"}, "pair_method"),
           ({"class_colours": {"chair": [2, 0, 0]}}, "class_colours")]
    for change, match in bad:
        with pytest.raises(ConfigError, match=match):
            LayerServerConfig.from_params({**params, **change})


def test_ellipse_axes_and_orientation_from_a_covariance():
    yaw = math.radians(30)
    rot = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    major, minor, angle = ellipse(rot @ np.diag([4.0, 1.0]) @ rot.T, n_sigma=2)
    assert (major, minor) == (pytest.approx(8.0), pytest.approx(4.0))
    assert math.sin(angle - yaw) == pytest.approx(0.0, abs=1e-9)  # same axis (modulo pi)
    assert class_colour("chair") == class_colour("chair") != class_colour("table")
    assert class_colour("chair", {"chair": (1.0, 0.0, 0.0)}) == (1.0, 0.0, 0.0)


def test_ospa_and_matching_scores_by_hand():
    est, truth = [(0.0, 0.0), (5.0, 5.0)], [(0.0, 0.3)]
    assert ospa(est, truth, cutoff=1.0) == pytest.approx((0.3 + 1.0) / 2)
    assert ospa([], [], cutoff=1.0) == 0.0 and ospa([], truth) == 1.0
    scores = match_scores(est, truth, radius=0.5)
    assert (scores["precision"], scores["recall"], scores["mean_error"]) == (0.5, 1.0, pytest.approx(0.3))
    assert match_scores([(0.0, 0.0)], [(0.0, 0.6)], radius=0.5)["recall"] == 0.0
