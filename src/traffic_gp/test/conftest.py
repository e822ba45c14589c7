"""Fixtures shared by the traffic_gp tests: one small simulated world and one GP fitted on it
(session-scoped: every module that needs the fitted GP shares the one fit)."""
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


@pytest.fixture(scope="session")
def small_world():
    """A two-room-per-side building in 1 m cells, two weeks of weekday views (rows merged per
    cell and 2 minutes, in time order)."""
    sim = PeopleSimulator.from_building(generate_building(4, rooms_per_side=2), 1.0, seed=5,
                                        peak_density=0.3)
    obs = Observations.from_views(sim.cells, weekday_views(sim, 150, 10)).compress(2 / 60.0, None)
    return sim, obs


@pytest.fixture(scope="session")
def fitted(small_world):
    """The GP with its serving (fallback, calibration) fitted on the small world's rows; its
    settings given, so no candidate search (test_selection covers the search)."""
    _, obs = small_world
    return TrafficGP(n_inducing=80, n_steps=250, batch_size=512, likelihood="poisson",
                     profile="none", refit_steps=50, random_state=0).fit(obs)
