"""Shared ROS helpers of lfd_controller's nodes."""

from robot_sim.maps import quaternion_to_yaw


def odom_state(msg):
    """(px, py, yaw, v, w) from a nav_msgs/Odometry."""
    pose, twist = msg.pose.pose, msg.twist.twist
    q = pose.orientation
    return [pose.position.x, pose.position.y, quaternion_to_yaw(q.x, q.y, q.z, q.w),
            twist.linear.x, twist.angular.z]


def single_threaded_blas() -> None:
    """Small matrices: BLAS threads only contend with other processes (10x slower under load)."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
