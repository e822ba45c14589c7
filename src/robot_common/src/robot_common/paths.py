"""Where ROS keeps per-user files, resolved one way for the whole workspace (no rospy needed)."""
import os
from pathlib import Path

__all__ = ["ros_home"]


def ros_home() -> Path:
    """$ROS_HOME, or ~/.ros as ROS itself defaults it."""
    return Path(os.environ.get("ROS_HOME") or Path.home() / ".ros")
