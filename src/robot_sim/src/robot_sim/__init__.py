"""Simulators with known ground truth: generated buildings, map files and sensor models."""
from robot_sim.building import Area, Building, PlacedObject, generate_building
from robot_sim.errors import MapError, SimError
from robot_sim.maps import FREE, OCCUPIED, UNKNOWN, GridMap, load_map, raycast, save_map

__all__ = [
    "Area",
    "Building",
    "PlacedObject",
    "generate_building",
    "MapError",
    "SimError",
    "FREE",
    "OCCUPIED",
    "UNKNOWN",
    "GridMap",
    "load_map",
    "raycast",
    "save_map",
]
