"""Path geometry: arc lengths, nearest points, distances, and whether a re-plan goes the same way."""
import numpy as np
import pytest

from robot_common.polylines import arc_lengths, distance_to, nearest_arc, point_at, same_way

# an L: 4 m east, then 3 m north
ELL = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]])


def test_arc_lengths_nearest_points_and_distances():
    assert arc_lengths(ELL).tolist() == [0.0, 4.0, 7.0]
    assert nearest_arc(ELL, (1.5, -0.5)) == pytest.approx((1.5, 0.5))
    assert nearest_arc(ELL, (5.0, 2.0)) == pytest.approx((6.0, 1.0))
    assert point_at(ELL, 5.5).tolist() == [4.0, 1.5]
    assert point_at(ELL, 99.0).tolist() == [4.0, 3.0]
    assert distance_to(ELL, [[2.0, 1.0], [6.0, 3.0], [-3.0, 4.0]]) == pytest.approx([1.0, 2.0, 5.0])
    assert nearest_arc(ELL[:1], (3.0, 4.0)) == pytest.approx((0.0, 5.0))


def test_a_re_plan_of_the_same_way_from_the_robot_or_a_little_off_it_goes_the_same_way():
    robot = (1.0, 0.0)
    assert same_way(ELL, ELL + [0.0, 0.3], robot, ahead=4.0)
    from_beside = np.array([[1.0, 0.8], [2.0, 0.0], [4.0, 0.0], [4.0, 3.0]])   # robot 0.8 m off
    assert same_way(ELL, from_beside, (1.0, 0.8), ahead=4.0)


def test_back_the_way_it_came_or_another_corridor_is_not_the_same_way():
    robot = (2.0, 0.0)
    assert not same_way(ELL, np.array([[2.0, 0.0], [0.0, 0.0], [0.0, 3.0], [4.0, 3.0]]), robot,
                        ahead=4.0)
    other = np.array([[2.0, 0.0], [2.0, 2.0], [4.0, 2.0], [4.0, 3.0]])     # cuts through a room
    assert not same_way(ELL, other, robot, ahead=4.0)
