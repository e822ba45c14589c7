"""Simulators with known ground truth: generated buildings, people, object detections, a unicycle
robot and its sensors. Maps, cells, the unicycle model and task geometry are robot_common's."""
from robot_sim.building import Area, Building, PlacedObject, generate_building
from robot_sim.errors import SimError

__all__ = ["Area", "Building", "PlacedObject", "generate_building", "SimError"]
