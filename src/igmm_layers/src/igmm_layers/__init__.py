"""Object layers: incremental Gaussian mixtures of object detections per class and map region.

Pure-Python core (no rospy): `IncrementalGMM` (igmm.py), `ClassHierarchy`, `LayerSet`/`Layer`
(layers.py), queries (queries.py), the node's parameters (params.py). The ROS node is in
ros_*.py and nodes/igmm_layers. Test and benchmark oracles (scores, the literal reference IGMM)
are in the `igmm_layers.sim` subpackage. Region search (phrases to labelled places) is its own
package, region_search, a client of the LocateObjects service.
"""
from igmm_layers.errors import (
    IGMMError,
    InvalidInputError,
    NotFittedError,
    PersistenceError,
    UnknownNameError,
)
from igmm_layers.hierarchy import ClassHierarchy
from igmm_layers.igmm import IncrementalGMM
from igmm_layers.layers import LAYER_KINDS, ClusterTable, Layer, LayerParams, LayerSet

__all__ = [
    "IncrementalGMM",
    "ClassHierarchy",
    "LayerSet",
    "Layer",
    "LayerParams",
    "ClusterTable",
    "LAYER_KINDS",
    "IGMMError",
    "InvalidInputError",
    "NotFittedError",
    "PersistenceError",
    "UnknownNameError",
]
