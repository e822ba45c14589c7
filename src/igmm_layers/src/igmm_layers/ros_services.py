"""The layer server's services: translate requests to queries on the layers, answers to responses.

Every response has `success` and `message`; a bad request (unknown region, layer, class or
group, bad mode/method/arguments, no database) gets success=False and a message naming the
problem, and never changes the layers. Other exceptions are bugs and reach the caller.
"""
import threading
from typing import Dict, List

import numpy as np
import rospy

from igmm_layers.cluster_store import load_cluster_set, save_cluster_set
from igmm_layers.errors import IGMMError, InvalidInputError, PersistenceError
from igmm_layers.layers import LAYER_KINDS, ClusterTable, check_kind
from igmm_layers.queries import alternate_classes, closest, count_observed, most_likely, pair_likelihood
from igmm_layers.ros_convert import cluster_msg, cluster_msgs, cluster_set
from igmm_layers.srv import (
    AlternateObject,
    CountObjects,
    LayerInfo,
    LoadClusters,
    LocateObjects,
    LookupObject,
    ObjectPairLikelihood,
    SaveClusters,
)

__all__ = ["LayerServices", "RESTORE_TIMEOUT"]

RESTORE_TIMEOUT = 30.0  # s to wait for a published cluster set to be applied


def _where(req) -> str:
    return f"{req.region_id or 'any region'}/{req.layer or 'objects'}"


class LayerServices:
    """Service handlers of a LayerServer (`server`); each runs with the layers locked."""

    def __init__(self, server):
        self.server = server
        self.layers = server.layers
        self._load_lock = threading.Lock()

    def setup(self) -> None:
        table = [("lookup_object", LookupObject, self.lookup, True),
                 ("pair_likelihood", ObjectPairLikelihood, self.pair, True),
                 ("alternate_object", AlternateObject, self.alternate, True),
                 ("locate_objects", LocateObjects, self.locate, True),
                 ("count_objects", CountObjects, self.count, True),
                 ("layer_info", LayerInfo, self.info, True),
                 # database calls lock only while they copy or replace the layers
                 ("save_clusters", SaveClusters, self.save, False),
                 ("load_clusters", LoadClusters, self.load, False)]
        self.services = [rospy.Service("~" + name, srv, self._guard(srv, handler, locked))
                         for name, srv, handler, locked in table]

    def _guard(self, srv, handler, locked: bool):
        response_class = srv._response_class

        def serve(req):
            try:
                if not locked:
                    return handler(req)
                with self.server.lock:
                    return handler(req)
            except IGMMError as err:
                return response_class(success=False, message=str(err))
        return serve

    # --- queries ------------------------------------------------------------------------------
    def lookup(self, req):
        table = self.layers.table(req.class_name, req.region_id, req.layer)
        what = f"{req.class_name!r} in {_where(req)}"
        point = [req.point.x, req.point.y, req.point.z]
        mode = req.mode or "most_likely"
        if mode == "most_likely":
            k = most_likely(table, what)
            distance = float(np.linalg.norm(table.means[k] - np.asarray(point[:table.means.shape[1]])))
        elif mode == "closest":
            k, distance = closest(table, point, what)
        else:
            raise InvalidInputError(f"unknown mode {req.mode!r}; modes: most_likely, closest")
        found = cluster_msg(table, k)
        return LookupObject._response_class(
            success=True, cluster=found, distance=distance,
            message=f"{mode}: {found.class_name} at ({found.mean.x:.2f}, {found.mean.y:.2f}) in "
                    f"{found.region_id}, support {found.support:.1f}, {distance:.2f} m from the point")

    def _nonempty(self, name: str, req) -> ClusterTable:
        table = self.layers.table(name, req.region_id, req.layer)
        if not len(table):
            raise InvalidInputError(f"no clusters of {name!r} in {_where(req)} yet")
        return table

    def pair(self, req):
        a, b = self._nonempty(req.class_a, req), self._nonempty(req.class_b, req)
        value, method, pairs = pair_likelihood(a, b, max_distance=req.max_distance or
                                               self.server.config.pair_max_distance,
                                               method=req.method or self.server.config.pair_method)
        return ObjectPairLikelihood._response_class(
            success=True, likelihood=value, method=method, pairs=pairs,
            message=f"{req.class_a} near {req.class_b}: {value:.4g} ({method}, {pairs} pairs)")

    def alternate(self, req):
        layers = self.layers.select(req.region_id, req.layer)
        target = set(self.layers.resolve(req.class_name, layers))
        names = list(req.candidates) or ["any"]
        candidates = sorted({c for name in names for c in self.layers.resolve(name, layers)} - target)

        def table_of(name: str) -> ClusterTable:
            return self.layers.table(name, req.region_id, req.layer)
        config = self.server.config
        ranked, method = alternate_classes(table_of, req.class_name, candidates,
                                           max_distance=req.max_distance or config.pair_max_distance,
                                           method=req.method or config.pair_method)
        best, value = ranked[0] if ranked else ("", 0.0)
        return AlternateObject._response_class(
            success=True, class_name=best, likelihood=value, method=method,
            ranked_classes=[c for c, _ in ranked], likelihoods=[v for _, v in ranked],
            message=f"near {req.class_name}: {best} ({value:.4g}, {method})" if best else
            f"no other class within range of {req.class_name}")

    def locate(self, req):
        table = self.layers.table(req.class_name, req.region_id, req.layer)
        message = f"{len(table)} clusters of {req.class_name!r} in {_where(req)}" if len(table) else \
            f"no clusters of {req.class_name!r} in {_where(req)} yet"
        return LocateObjects._response_class(success=True, message=message, clusters=cluster_msgs(table))

    def count(self, req):
        layers = self.layers.select(req.region_id, req.layer)
        names = list(req.class_names) or self.layers.resolve("any", layers)
        window = {"start": None if req.start.is_zero() else req.start.to_sec(),
                  "end": None if req.end.is_zero() else req.end.to_sec(),
                  "center": [req.center.x, req.center.y, req.center.z], "radius": req.radius}
        counts, observations = [], []
        for name in names:
            classes = self.layers.resolve(name, layers)
            table = ClusterTable.concat([layer.table(classes) for layer in layers])
            found: Dict[str, tuple] = count_observed(table, **window)
            counts.append(sum(c for c, _ in found.values()))
            observations.append(sum(o for _, o in found.values()))
        return CountObjects._response_class(
            success=True, class_names=names, counts=counts, observations=observations,
            message=", ".join(f"{n}: {c}" for n, c in zip(names, counts)) or "no classes")

    def info(self, req):
        received, applied, dropped, reason = self.server.counters()
        layers = [layer for _, layer in sorted(self.layers.layers.items())]
        keys = [(layer.region_id, layer.kind) for layer in layers]
        return LayerInfo._response_class(
            success=True, message="; ".join(filter(None, [f"{len(layers)} layers",
                                                          self.server.learned_status()])),
            region_ids=[k[0] for k in keys],
            layers=[k[1] for k in keys], observation_topics=[self.server.topics.get(k, "") for k in keys],
            classes=[len(layer.classes) for layer in layers],
            clusters=[layer.n_clusters() for layer in layers],
            components=[layer.n_clusters(confirmed_only=False) for layer in layers],
            marker_updates=[self.server.marker_updates(k) for k in keys],
            received=received, applied=applied, dropped=dropped, last_drop_reason=reason)

    # --- persistence --------------------------------------------------------------------------
    def save(self, req):
        kinds: List[str] = [check_kind(req.layer)] if req.layer else list(LAYER_KINDS)
        with self.server.lock:
            layers = [layer for kind in kinds for layer in self.layers.select(req.region_id, kind)]
            msg = cluster_set(layers, rospy.Time.now(), self.server.config.map_frame)
        doc_id, tag = save_cluster_set(self.server.config.db_url, msg,
                                       self.server.config.robot_id)
        return SaveClusters._response_class(
            success=True, id=doc_id, timestamp=tag, clusters=len(msg.clusters),
            message=f"saved {len(msg.clusters)} clusters of {len(layers)} layers as {tag}")

    def load(self, req):
        with self._load_lock:
            msg, doc_id, tag = load_cluster_set(self.server.config.db_url, req.timestamp)
            result = self.server.publish_restore(msg, RESTORE_TIMEOUT)
        if result is None:
            raise PersistenceError(f"published set {tag} on ~restore, but it was not applied "
                                   f"within {RESTORE_TIMEOUT:.0f} s")
        if isinstance(result, Exception):
            raise PersistenceError(f"saved set {tag} cannot be restored: {result}")
        n_layers, n_clusters = result
        return LoadClusters._response_class(
            success=True, id=doc_id, timestamp=tag, clusters=n_clusters,
            message=f"loaded {n_clusters} clusters into {n_layers} layers from set {tag}")
