"""`path_msg`: the one nav_msgs/Path builder (the demo's path, reward_controller's ~plan,
errand_server's plans). No roscore: it only builds messages."""
import math

import numpy as np
import pytest
import rospy

from robot_common.ros_node import path_msg

HALF = math.sqrt(0.5)       # sin and cos of 45 degrees: a yaw of 90 degrees is (0, 0, HALF, HALF)


def poses_xy(msg):
    return [(p.pose.position.x, p.pose.position.y) for p in msg.poses]


def quaternions(msg):
    return [(p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z, p.pose.orientation.w)
            for p in msg.poses]


def test_frame_and_stamp_go_on_the_path_and_on_every_pose():
    stamp = rospy.Time(12, 500)
    msg = path_msg([(0.0, 0.0), (1.0, 2.0)], "lfd/odom", stamp)
    assert msg.header.frame_id == "lfd/odom" and msg.header.stamp == stamp
    assert [(p.header.frame_id, p.header.stamp) for p in msg.poses] == [("lfd/odom", stamp)] * 2
    assert poses_xy(msg) == [(0.0, 0.0), (1.0, 2.0)]


def test_without_a_stamp_or_headings_the_path_is_unstamped_and_unrotated():
    msg = path_msg([(3.0, -1.0), (4.0, -1.0)], "map")
    assert msg.header.stamp == rospy.Time(0) and msg.poses[1].header.stamp == rospy.Time(0)
    assert quaternions(msg) == [(0.0, 0.0, 0.0, 1.0)] * 2


def test_each_pose_may_carry_its_own_stamp():
    stamps = [rospy.Time(5), rospy.Time(6), rospy.Time(8)]
    msg = path_msg([(0, 0), (1, 0), (2, 0)], "map", rospy.Time(5), stamps=stamps)
    assert [p.header.stamp for p in msg.poses] == stamps and msg.header.stamp == rospy.Time(5)


def test_headings_along_a_straight_path_point_to_the_next_point():
    # down and to the left at 45 degrees: every yaw is -135 degrees
    msg = path_msg([(2, 2), (1, 1), (0, 0)], "map", headings="along")
    z, w = math.sin(-3 * math.pi / 8), math.cos(-3 * math.pi / 8)
    np.testing.assert_allclose(quaternions(msg), [(0.0, 0.0, z, w)] * 3, atol=1e-12)


def test_headings_along_a_corner_point_from_the_point_before_to_the_point_after():
    # east, then north: the first pose faces east (yaw 0), the corner faces from (0, 0) to
    # (1, 1) (45 degrees), the last faces from (1, 0) to (1, 1) (north, 90 degrees)
    msg = path_msg([(0, 0), (1, 0), (1, 1)], "map", headings="along")
    eighth = (math.sin(math.pi / 8), math.cos(math.pi / 8))
    np.testing.assert_allclose(quaternions(msg), [(0, 0, 0, 1), (0, 0, *eighth), (0, 0, HALF, HALF)],
                               atol=1e-12)


def test_given_headings_are_used_as_they_are():
    msg = path_msg([(0, 0), (1, 0)], "map", headings=[math.pi / 2, math.pi])
    np.testing.assert_allclose(quaternions(msg), [(0, 0, HALF, HALF), (0, 0, 1, 0)], atol=1e-12)


def test_an_empty_path_has_its_header_and_no_poses():
    # reward_controller has no plan before its first cycle: it publishes such a path
    msg = path_msg([], "odom", rospy.Time(3), headings=[])
    assert msg.poses == [] and msg.header.frame_id == "odom" and msg.header.stamp == rospy.Time(3)


def test_a_lone_point_along_the_path_faces_yaw_zero():
    # errand_server's plan when the robot is already there
    msg = path_msg([(4.0, 5.0)], "map", headings="along")
    assert poses_xy(msg) == [(4.0, 5.0)] and quaternions(msg) == [(0.0, 0.0, 0.0, 1.0)]


@pytest.mark.parametrize("points, options, message", [
    ([1.0, 2.0], {}, r"\(N, 2\).*\(2,\)"),
    ([(0, 0, 0)], {}, r"\(N, 2\).*\(1, 3\)"),
    ([(0, 0), (1, 0)], {"headings": [0.0]}, "1 headings for 2 path points"),
    ([(0, 0), (1, 0)], {"headings": "ahead"}, "'ahead'"),
    ([(0, 0), (1, 0)], {"stamps": [rospy.Time(1)]}, "1 pose stamps for 2 path points"),
])
def test_bad_input_gets_a_clear_error(points, options, message):
    with pytest.raises(ValueError, match=message):
        path_msg(points, "map", **options)
