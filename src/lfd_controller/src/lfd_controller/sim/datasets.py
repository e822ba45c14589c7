"""Demonstration sets from simulated people, and two layouts no standard scenario shows (no ROS)."""
from typing import List, Optional, Sequence

import numpy as np

from lfd_controller.demos import Demonstration
from lfd_controller.sim.families import make_person
from robot_common.tasks import Scenario, scenario_from_dict


def person_demos(scenario: Scenario, family: str, starts: Sequence[np.ndarray], seed: int = 0,
                 only_successful: bool = True, max_tries: int = 3, person=None,
                 wanted: Optional[int] = None) -> List[Demonstration]:
    """Demonstrations by one person of `family` (drawn from `seed` unless `person` is given) from
    `starts`, at most `wanted` (None: one per start). Like people keeping good takes, a drive that
    collides or times out is re-done (the same person, another day) up to max_tries times; with
    only_successful it is left out after that."""
    driver = make_person(family, seed, person)
    demos = []
    for start in starts:
        if wanted is not None and len(demos) >= wanted:
            break
        for _ in range(max_tries):
            demo = driver.demonstrate(scenario, start)
            if demo.meta["reached"]:
                break
        if demo.meta["reached"] or not only_successful:
            demos.append(demo)
    return demos


def dart_demos(scenario: Scenario, family: str, starts: Sequence[np.ndarray], seed: int = 0,
               noise: Sequence[float] = (0.1, 0.4), person=None) -> List[Demonstration]:
    """DART data for behaviour cloning (Laskey et al. 2017): the same person's drives with noise
    injected into the executed commands; states are the ones reached, actions the person's own."""
    driver = make_person(family, seed, person)
    demos = []
    for start in starts:
        actions, states, reached, _, _ = driver.drive(scenario, start, execution_noise=noise)
        if len(actions) >= 2:
            demos.append(Demonstration(scenario, start, actions, 0.0, states,
                                       source=f"person:{family}:dart",
                                       meta=dict(driver.describe(), reached=bool(reached))))
    return demos


def unseen_layouts() -> List[Scenario]:
    """Two obstacle/goal layouts no standard scenario shows (for generalisation figures)."""
    base = {"dt": 0.1, "max_time": 15.0, "bounds": [-3.5, -2.0, 1.0, 2.0],
            "robot": {"radius": 0.18, "v_max": 0.6, "w_max": 2.0, "a_max": 1.0, "alpha_max": 4.0},
            "start": {"x": [-2.7, -2.2], "y": [-0.9, 0.9], "yaw": [-0.6, 0.6]}}
    offset = dict(base, name="layout_offset_goal", goal={"x": 0.2, "y": 0.9, "tolerance": 0.25},
                  obstacle={"x": -1.0, "y": 0.4, "radius": 0.3, "motion": {"kind": "static"}})
    crossing = dict(base, name="layout_crossing", goal={"x": 0.0, "y": -0.8, "tolerance": 0.25},
                    obstacle={"x": -1.5, "y": 1.0, "radius": 0.22,
                              "motion": {"kind": "linear", "velocity": [0.0, -0.2]}})
    return [scenario_from_dict(offset), scenario_from_dict(crossing)]
