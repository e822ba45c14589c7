"""Shared ROS helpers of lfd_controller's nodes."""
import logging

import rospy

from robot_sim.maps import quaternion_to_yaw


def odom_state(msg):
    """(px, py, yaw, v, w) from a nav_msgs/Odometry."""
    pose, twist = msg.pose.pose, msg.twist.twist
    q = pose.orientation
    return [pose.position.x, pose.position.y, quaternion_to_yaw(q.x, q.y, q.z, q.w),
            twist.linear.x, twist.angular.z]


class RosoutHandler(logging.Handler):
    """Routes the core's logging to rosout (installed once per node)."""

    def emit(self, record):
        text = self.format(record)
        if record.levelno >= logging.ERROR:
            rospy.logerr(text)
        elif record.levelno >= logging.WARNING:
            rospy.logwarn(text)
        else:
            rospy.loginfo(text)


def route_logging() -> None:
    logger = logging.getLogger("lfd_controller")
    if not any(isinstance(h, RosoutHandler) for h in logger.handlers):
        logger.addHandler(RosoutHandler())
        logger.setLevel(logging.INFO)


def single_threaded_blas() -> None:
    """Small matrices: BLAS threads only contend with other processes (10x slower under load)."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
