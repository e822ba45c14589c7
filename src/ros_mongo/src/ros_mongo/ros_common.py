"""What the ros_mongo nodes share: private parameters with defaults, and the core's logging on rosout.

`route_logging` serves every package of the workspace (igmm_layers, traffic_gp, lfd_controller
import it from here)."""
import logging
import os
from pathlib import Path
from typing import Any, Dict

import rospy

__all__ = ["read_params", "route_logging", "ros_home", "ConfigError"]


class ConfigError(ValueError):
    """A node parameter has a bad value (the node exits with one readable line)."""


class _RospyHandler(logging.Handler):
    def emit(self, record: logging.LogRecord) -> None:
        text = self.format(record)
        if record.levelno >= logging.ERROR:
            rospy.logerr(text)
        elif record.levelno >= logging.WARNING:
            rospy.logwarn(text)
        elif record.levelno >= logging.INFO:
            rospy.loginfo(text)
        else:
            rospy.logdebug(text)


def route_logging(logger_name: str = "ros_mongo") -> None:
    """Send the log records of a pure-Python core (logger `logger_name`) to rosout (once)."""
    logger = logging.getLogger(logger_name)
    if not any(isinstance(h, _RospyHandler) for h in logger.handlers):
        logger.addHandler(_RospyHandler())
        logger.setLevel(logging.INFO)
        logger.propagate = False


def read_params(defaults: Dict[str, Any]) -> Dict[str, Any]:
    """Private parameters `~key` for every key of `defaults`, checked against the default's type."""
    params = {}
    for key, default in defaults.items():
        value = rospy.get_param("~" + key, default)
        if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if default is not None and not isinstance(value, type(default)):
            raise ConfigError(f"parameter ~{key} must be a {type(default).__name__}, got {value!r}")
        params[key] = value
    return params


def ros_home() -> Path:
    return Path(os.environ.get("ROS_HOME") or Path.home() / ".ros")
