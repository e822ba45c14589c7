"""Shared data for lfd_controller's tests: synthetic expert demonstrations (computed once)."""
import numpy as np
import pytest

from lfd_controller.expert import SyntheticExpert
from robot_sim.scenarios import load_scenario


@pytest.fixture(scope="session")
def static_scenario():
    return load_scenario("static_obstacle")


@pytest.fixture(scope="session")
def expert_demos(static_scenario):
    """Six 40-step demonstrations optimal under the known reward (TRUE_WEIGHTS)."""
    expert = SyntheticExpert(steps=40, max_iter=150)
    starts = static_scenario.sample_starts(6, seed=11)
    return expert.demonstrations(static_scenario, starts)


@pytest.fixture(scope="session")
def true_weights():
    from lfd_controller.expert import true_reward

    return true_reward().weights


def cosine(a, b) -> float:
    return float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))


@pytest.fixture(scope="session", autouse=True)
def single_threaded_blas():
    """The learning core works on small matrices: BLAS threads only contend on a shared machine."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        yield
