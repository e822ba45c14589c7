"""The demonstrations chapter's scene and figures, without running it (no ROS)."""
import threading
from types import SimpleNamespace

import numpy as np


def test_the_scene_runs_from_the_main_hall_round_the_corner_into_the_back_hall():
    from robot_demo.chapters.demonstrations import GOAL, START, make_scene
    from robot_sim.building import generate_building

    halls = {area.name: area.box for area in generate_building(0).halls}
    scene = make_scene()

    def inside(point, box):
        return box[0] <= point[0] <= box[2] and box[1] <= point[1] <= box[3]
    assert inside(START, halls["main_hall"]) and inside(GOAL, halls["back_hall"])
    # along the halls: 26.2 - 18.0 = 8.2 m east, then 10.5 - 6.7 = 3.8 m north (12 m), less
    # what the corner cuts
    assert 10.0 < scene.length < 12.0
    assert np.allclose(scene.path[0], START[:2]) and np.allclose(scene.path[-1], GOAL)
    assert scene.grid.is_free(scene.path[:, 0], scene.path[:, 1]).all()


def test_the_closest_approach_to_people_is_edge_to_edge():
    from robot_demo.app import Demo
    from robot_demo.chapters.demonstrations import scene_gap

    gap = scene_gap(Demo)
    # the nearer person 1 m from the robot's centre: 1 - 0.18 (robot) - 0.25 (person) = 0.57 m
    people = np.array([[3.0, 3.0], [6.0, 3.0]])
    assert abs(gap(np.array([2.0, 3.0, 0.0, 0.0, 0.0]), people) - 0.57) < 1e-9


def test_a_drive_succeeds_only_at_the_goal_without_a_collision():
    from robot_demo.chapters.demonstrations import describe, result

    def drive(arrived, status):
        return result(SimpleNamespace(lock=threading.Lock(), arrived=arrived, status=status,
                                      closest=0.3))
    reached = drive(251, "running")
    assert reached["success"] and abs(reached["time"] - 25.1) < 1e-9     # 251 steps of 0.1 s
    assert describe(reached).startswith("at the goal after 25.1 s")
    hit = drive(251, "collided with person")
    assert not hit["success"] and hit["collision"] == "collided with person"
    lost = drive(None, "running")
    assert not lost["success"] and "did not reach" in describe(lost)
