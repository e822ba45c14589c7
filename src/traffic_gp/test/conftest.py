"""Fixtures shared by the traffic_gp tests: one small simulated world and one GP fitted on it
(session-scoped: every module that needs the fitted GP shares the one fit; with pytest-xdist the
first worker that needs it fits and saves it, the others load that file)."""
import fcntl
import os
from contextlib import contextmanager

import pytest

from robot_sim import generate_building
from robot_sim.people import PeopleSimulator
from traffic_gp.model import TrafficGP
from traffic_gp.observations import Observations


def weekday_views(sim, per_day, days):
    """`per_day` views of two robots on each of `days` weekdays (Monday to Friday)."""
    views = []
    for day in range(days):
        week, weekday = divmod(day, 5)
        views += sim.observe(per_day, robots=2, start=(week * 7 + weekday) * 24.0, hours=24.0,
                             radius=4.0)
    return views


@contextmanager
def _locked(path):
    """An exclusive lock on `path` (a file) across the processes of one pytest run."""
    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def shared_fit(tmp_path_factory, name: str, fit):
    """`fit()` once per test run: in a single process as it is; under pytest-xdist the first
    worker fits and saves the model (its own `save`), the other workers `TrafficGP.load` it."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return fit()
    shared = tmp_path_factory.getbasetemp().parent          # the run's, common to the workers
    path = shared / f"{name}.npz"
    with _locked(shared / f"{name}.lock"):
        if path.exists():
            return TrafficGP.load(path)
        model = fit()
        model.save(path)
        return model


@pytest.fixture(scope="session")
def small_world():
    """A two-room-per-side building in 1 m cells, two weeks of weekday views (rows merged per
    cell and 2 minutes, in time order)."""
    sim = PeopleSimulator.from_building(generate_building(4, rooms_per_side=2), 1.0, seed=5,
                                        peak_density=0.3)
    obs = Observations.from_views(sim.cells, weekday_views(sim, 150, 10)).compress(2 / 60.0, None)
    return sim, obs


@pytest.fixture(scope="session")
def fitted(small_world, tmp_path_factory):
    """The GP with its serving (fallback, calibration) fitted on the small world's rows; its
    settings given, so no candidate search (test_selection covers the search)."""
    _, obs = small_world
    # 150 + 30 steps: its error on the true pattern is under half the binned mean's, and it
    # beats both baselines on the held-out day (test_model, test_serving)
    return shared_fit(tmp_path_factory, "traffic_gp_fitted", lambda: TrafficGP(
        n_inducing=80, n_steps=150, batch_size=512, likelihood="poisson", profile="none",
        refit_steps=30, random_state=0).fit(obs))
