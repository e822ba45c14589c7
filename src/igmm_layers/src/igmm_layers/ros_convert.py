"""Messages <-> layer core: clusters, cluster sets (save/restore), markers, observation sizes."""
import math
from typing import Dict, List, Sequence, Tuple

import numpy as np
import rospy
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from igmm_layers.errors import InvalidInputError
from igmm_layers.layers import ClusterTable, Layer, LayerSet, check_kind
from igmm_layers.msg import ClusterSet, ObjectCluster
from igmm_layers.visual import class_colour, ellipse

__all__ = ["cluster_msg", "cluster_msgs", "cluster_set", "apply_cluster_set", "layer_markers",
           "size_covariance", "rotation_matrix", "to_time"]


def to_time(seconds: float) -> rospy.Time:
    return rospy.Time.from_sec(max(float(seconds), 0.0))


def _cov3(cov: np.ndarray) -> List[float]:
    full = np.zeros((3, 3))
    dim = min(cov.shape[0], 3)
    full[:dim, :dim] = cov[:dim, :dim]
    return full.ravel().tolist()


def cluster_msg(table: ClusterTable, k: int) -> ObjectCluster:
    mean = np.zeros(3)
    mean[:table.means.shape[1]] = table.means[k][:3]
    return ObjectCluster(class_name=table.class_names[k], region_id=table.region_ids[k],
                         layer=table.kinds[k], mean=Point(*mean.tolist()),
                         covariance=_cov3(table.covariances[k]), weight=float(table.weights[k]),
                         support=float(table.support[k]), observations=int(table.observations[k]),
                         first_seen=to_time(table.first_seen[k]), last_seen=to_time(table.last_seen[k]))


def cluster_msgs(table: ClusterTable) -> List[ObjectCluster]:
    return [cluster_msg(table, k) for k in range(len(table))]


def cluster_set(layers: Sequence[Layer], stamp: rospy.Time, frame_id: str) -> ClusterSet:
    """Every component (tentative ones too) of the layers, with observation times."""
    msg = ClusterSet()
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    for layer in layers:
        msg.layers.append(f"{layer.region_id}/{layer.kind}")
        table = layer.table(sorted(layer.models), confirmed_only=False)
        msg.clusters += cluster_msgs(table)
        msg.time_counts += [len(times) for times in table.times]
        msg.observation_times += [to_time(t) for times in table.times for t in times]
    return msg


def apply_cluster_set(layers: LayerSet, msg: ClusterSet) -> Tuple[int, int]:
    """Replace the layers the set covers by its clusters; returns (layers, clusters) restored.

    Everything is checked before anything changes, so a bad set leaves the layers untouched.
    """
    if len(msg.time_counts) not in (0, len(msg.clusters)) or \
            sum(msg.time_counts) != len(msg.observation_times):
        raise InvalidInputError("cluster set: time_counts do not match clusters and observation_times")
    bad = [name for name in msg.layers if "/" not in name]
    covered = [tuple(name.rsplit("/", 1)) for name in msg.layers if "/" in name]
    covered += [(c.region_id, c.layer) for c in msg.clusters]
    if bad or any(not region for region, _ in covered):
        raise InvalidInputError(f"cluster set: a layer or cluster without a region id {bad[:3]}")
    keys = sorted({(region, check_kind(kind)) for region, kind in covered})
    states = _class_states(msg, layers)
    staged = {}
    for key in keys:
        layer = Layer(key[0], key[1], layers.params_for(*key))
        for (region, kind, class_name), state in states.items():
            if (region, kind) == key:
                layer.restore_class(class_name, state)
        staged[key] = layer
    layers.layers.update(staged)
    return len(staged), len(msg.clusters)


def _class_states(msg: ClusterSet, layers: LayerSet) -> Dict[Tuple[str, str, str], dict]:
    dim = layers.defaults.dimensions
    states: Dict[Tuple[str, str, str], dict] = {}
    offset = 0
    for i, cluster in enumerate(msg.clusters):
        count = msg.time_counts[i] if msg.time_counts else 0
        times = [t.to_sec() for t in msg.observation_times[offset:offset + count]]
        offset += count
        mean = [cluster.mean.x, cluster.mean.y, cluster.mean.z][:dim]
        cov = np.asarray(cluster.covariance, dtype=float).reshape(3, 3)[:dim, :dim]
        key = (cluster.region_id, check_kind(cluster.layer), cluster.class_name)
        if not cluster.class_name:
            raise InvalidInputError(f"cluster set: cluster {i} has no class name")
        state = states.setdefault(key, {"fitted": True, "n_features_in": dim, "components": []})
        state["components"].append({"mean": mean, "covariance": cov.tolist(),
                                     "support": cluster.support, "age": max(int(cluster.observations), 1),
                                     "first_seen": cluster.first_seen.to_sec(),
                                     "last_seen": cluster.last_seen.to_sec(), "times": times})
    return states


def layer_markers(layer: Layer, frame_id: str, stamp: rospy.Time,
                  colours: Dict[str, Tuple[float, float, float]]) -> MarkerArray:
    """DELETEALL, then per confirmed cluster a flat 2-sigma ellipse and a text label."""
    markers = MarkerArray()
    clear = Marker(action=Marker.DELETEALL)
    clear.header.frame_id, clear.header.stamp = frame_id, stamp
    markers.markers.append(clear)
    table = layer.table(layer.classes)
    for k in range(len(table)):
        name = table.class_names[k]
        rgb = class_colour(name, colours)
        major, minor, yaw = ellipse(table.covariances[k])
        x, y = float(table.means[k][0]), float(table.means[k][1])
        shape = Marker(type=Marker.CYLINDER, action=Marker.ADD, ns="clusters", id=k)
        shape.pose.position.x, shape.pose.position.y, shape.pose.position.z = x, y, 0.05
        shape.pose.orientation.z, shape.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
        shape.scale.x, shape.scale.y, shape.scale.z = max(major, 0.02), max(minor, 0.02), 0.05
        shape.color = ColorRGBA(rgb[0], rgb[1], rgb[2], 0.8)
        label = Marker(type=Marker.TEXT_VIEW_FACING, action=Marker.ADD, ns="labels", id=k, text=name)
        label.pose.position.x, label.pose.position.y, label.pose.position.z = x, y + 0.3, 0.5
        label.pose.orientation.w = 1.0
        label.scale.z = 0.3
        label.color = ColorRGBA(0.05, 0.05, 0.05, 0.95)
        for marker in (shape, label):
            marker.header.frame_id, marker.header.stamp = frame_id, stamp
            markers.markers.append(marker)
    return markers


def rotation_matrix(q) -> np.ndarray:
    """3x3 rotation of a geometry_msgs/Quaternion (normalised first)."""
    x, y, z, w = q.x, q.y, q.z, q.w
    norm = math.sqrt(x * x + y * y + z * z + w * w) or 1.0
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def size_covariance(size, rotation: np.ndarray) -> np.ndarray:
    """Measurement covariance of an object of extent `size` (x, y, z): a uniform spread over the
    box, variance s^2 / 12 per axis, rotated into the map frame."""
    local = np.diag(np.array([size.x, size.y, size.z], dtype=float) ** 2 / 12.0)
    return rotation @ local @ rotation.T
