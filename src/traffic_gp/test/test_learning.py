"""The node's learner (no ROS): the baselines are served at once, the GP is chosen and fitted in
the background, rows that come meanwhile are served at once and reach the GP when it replaces
the baselines; a refit once the rows have doubled since the last fit, not before."""
import threading

import numpy as np
import pytest

from robot_common.cells import CellGrid
from robot_sim import generate_building
from traffic_gp.learning import Learner
from traffic_gp.model import TrafficGP
from traffic_gp.observations import Observations
from traffic_gp.quick import BaselineForecast

PARAMS = {"n_inducing": 5, "n_steps": 5, "hourly": False, "likelihood": "poisson",
          "profile": "none", "spatial_inputs": "xy", "refit_steps": 0, "online_steps": 5}


class GatedLearner(Learner):
    """Holds each background fit until the test opens the gate (the fit itself is the real one):
    what is served while a fit runs can then be checked without racing it."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.gate = threading.Event()

    def _fit_gp(self, *args):
        assert self.gate.wait(600), "the test never opened the gate"
        return super()._fit_gp(*args)


@pytest.fixture(scope="module")
def cells():
    return CellGrid.from_map(generate_building(0).grid, 0.5)


def rows_of(robot: str, cells, first: int, hour: float, count: int, n: int = 40):
    pick = slice(first, first + n)
    return Observations(cells.x[pick], cells.y[pick], np.full(n, hour), np.full(n, 0.25),
                        np.full(n, count), robot=[robot] * n)


def finish(learner, cells):
    learner.job.thread.join(600)
    learner.step(cells, threading.Event(), trained=False)


def test_rows_of_a_new_robot_are_served_while_the_gp_is_still_being_fitted(cells):
    learner = GatedLearner(PARAMS, min_rows=40, initial_steps=5, refit_growth=0,
                           reselect_growth=0, chunk_steps=5)
    learned, said_at_commit = [], []
    assert not learner.add(rows_of("r1", cells, 0, 10.0, 1, n=20), cells, lambda: None)
    assert learner.model is None, "fewer than min_rows: nothing served, the caller keeps them"

    def commit_r1():
        learned.append("r1")
        said_at_commit.append(learner.describe())

    # `commit` runs under the lock the services answer under: what an answer sees the moment the
    # baselines are served must already say that the GP is being chosen, not "no GP yet"
    assert learner.add(rows_of("r1", cells, 0, 10.0, 1), cells, commit_r1)
    assert isinstance(learner.model, BaselineForecast) and learned == ["r1"]
    assert said_at_commit[0].startswith(
        "serving the baselines while the GP is selected and fitted; "
        "choosing the GP's settings and fitting it"), said_at_commit
    with learner.lock:
        assert "serving the baselines while the GP is selected and fitted" in learner.describe()
    assert "not the GP" in learner.model.status()

    far = 400                               # cells the first robot never saw
    assert learner.add(rows_of("r2", cells, far, 10.0, 5), cells, lambda: learned.append("r2"))
    assert learned == ["r1", "r2"] and learner.model.n_rows_ == 80
    assert learner.job is not None and not learner.job.done(), "the fit is held at the gate"
    x, y = cells.x[far:far + 40], cells.y[far:far + 40]
    served = learner.model.predict(x, y, np.full(40, 10.0), 0.25)
    np.testing.assert_allclose(served, 5.0, rtol=1e-6)      # the new robot's counts, served

    learner.gate.set()
    finish(learner, cells)
    assert isinstance(learner.model, TrafficGP) and learner.job is None
    assert learner.model.n_rows_ == 80, "rows that came during the fit reach the GP"
    assert learner.describe() == "serving the GP" and learner.serving_note() == ""


def test_the_gp_is_refitted_warm_once_the_rows_have_doubled_not_before(cells):
    learner = Learner(PARAMS, min_rows=40, initial_steps=5, refit_growth=2.0,
                      reselect_growth=0, chunk_steps=5)
    stop = threading.Event()
    learner.add(rows_of("r1", cells, 0, 10.0, 1), cells, lambda: None)
    finish(learner, cells)
    first = learner.model
    assert isinstance(first, TrafficGP) and learner.job_rows == 40
    learner.add(rows_of("r1", cells, 40, 11.0, 1), cells, lambda: None)   # 80: doubled
    learner.step(cells, stop, trained=True)
    assert learner.job is not None and learner.job.kind == "refit" and learner.job.rows == 80
    finish(learner, cells)
    second = learner.model
    assert second is not first and second.n_rows_ == 80
    assert second.settings_ == first.settings_
    assert second.selection_["reason"].startswith("refitted on 80 rows, warm")
    learner.add(rows_of("r1", cells, 80, 12.0, 1), cells, lambda: None)   # 120: not yet
    learner.step(cells, stop, trained=True)
    assert learner.job is None and learner.model is second and second.n_rows_ == 120
