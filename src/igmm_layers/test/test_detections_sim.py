"""robot_sim.detections: the detection simulator that the layer tests, bench and demo rely on."""
import numpy as np
import pytest

from robot_sim import SimError, generate_building
from robot_sim.detections import building_scene, random_scene, scene_bounds, simulate_detections


def test_random_scene_keeps_objects_apart_inside_bounds_and_is_reproducible():
    scene = random_scene(15, bounds=[(0, 10), (0, 10), (0, 2)], min_separation=1.0, random_state=3)
    positions = np.array([obj.position for obj in scene])
    assert positions.shape == (15, 3) and np.all(positions >= 0) and np.all(positions[:, :2] <= 10)
    gaps = np.linalg.norm(positions[:, None] - positions[None], axis=2) + np.eye(15) * 99
    assert gaps.min() >= 1.0
    assert scene == random_scene(15, bounds=[(0, 10), (0, 10), (0, 2)], min_separation=1.0, random_state=3)
    with pytest.raises(SimError, match="could not place"):
        random_scene(50, bounds=[(0, 2), (0, 2)], min_separation=1.0, random_state=0)


def test_detections_have_poisson_counts_gaussian_noise_clutter_and_random_order():
    scene = random_scene(40, bounds=[(0, 50), (0, 50)], random_state=1)
    dets = simulate_detections(scene, mean_detections=30, noise_std=0.2, clutter_fraction=0.1,
                               random_state=2, start_time=100.0, duration=10.0)
    real = dets.truth >= 0
    counts = np.bincount(dets.truth[real], minlength=40)
    assert 25 < counts.mean() < 35 and counts.var() > 5  # Poisson(30): mean = variance = 30
    assert dets.clutter_fraction == pytest.approx(0.1, abs=0.005)
    truth_pos = np.array([obj.position for obj in scene])
    noise = dets.positions[real] - truth_pos[dets.truth[real]]
    assert np.std(noise) == pytest.approx(0.2, rel=0.1) and abs(np.mean(noise)) < 0.02
    box = scene_bounds(scene)
    assert np.all(dets.positions[~real] >= box[:, 0]) and np.all(dets.positions[~real] <= box[:, 1])
    assert np.any(np.diff(dets.truth[real]) < 0)  # shuffled, not object by object
    assert np.all(np.diff(dets.stamps) >= 0) and 100.0 <= dets.stamps[0] and dets.stamps[-1] <= 110.0
    assert set(dets.class_names) == {"object"}
    again = simulate_detections(scene, mean_detections=30, noise_std=0.2, clutter_fraction=0.1,
                                random_state=2, start_time=100.0, duration=10.0)
    np.testing.assert_array_equal(again.positions, dets.positions)


def test_building_scene_is_the_generated_ground_truth():
    building = generate_building(0)
    scene = building_scene(building)
    truth = [(o.class_name, (o.x, o.y)) for o in building.objects]
    assert [(o.class_name, o.position) for o in scene] == truth
    dets = simulate_detections(scene, extent_spread=True, noise_std=0.0, clutter_fraction=0.0,
                               random_state=0)
    couch = [i for i, o in enumerate(scene) if o.class_name == "couch"][0]
    spread = np.abs(dets.positions[dets.truth == couch] - scene[couch].position)
    assert np.all(spread <= np.array(scene[couch].size) / 2 + 1e-9) and spread[:, 0].max() > 0.5
    chairs = dets.of_class("chair")
    assert set(chairs.class_names) == {"chair"} and len(chairs) == np.sum(
        [scene[t].class_name == "chair" for t in dets.truth])


def test_bad_arguments_are_refused():
    scene = random_scene(2, random_state=0)
    with pytest.raises(SimError, match="clutter_fraction"):
        simulate_detections(scene, clutter_fraction=1.0)
    with pytest.raises(SimError, match="no objects"):
        simulate_detections([])
    with pytest.raises(SimError, match="bounds"):
        simulate_detections(scene, bounds=[(0, 1)])
