"""Fixtures of the igmm_layers tests: a real layer server (node `igmm_layers`) per test module,
and a helper that publishes observations and waits until the server has taken all of them in."""
import uuid
from pathlib import Path
from typing import Dict, Optional

import pytest
import yaml

from igmm_layers.srv import LayerInfo
from robot_common.msg import ObjectObservation
from ros_harness import RosLaunch, wait_for_subscriber, wait_until

CONFIG = Path(__file__).resolve().parent.parent / "config" / "igmm_layers.yaml"
SERVICES = ["lookup_object", "pair_likelihood", "alternate_object", "locate_objects", "count_objects",
            "save_clusters", "load_clusters", "layer_info"]


def server_params(**overrides) -> Dict[str, object]:
    """The shipped defaults (config/igmm_layers.yaml) with some parameters changed."""
    params = yaml.safe_load(CONFIG.read_text())
    params.update(overrides)
    return params


def start_server(roscore, log_dir: Path, params: Dict[str, object], name: str = "igmm_layers") -> RosLaunch:
    launch = RosLaunch.node("igmm_layers", "igmm_layers", name=name, master_uri=roscore.uri,
                            log_dir=log_dir, env=roscore.env(), params=params).start()
    launch.wait_for_services([f"/{name}/{service}" for service in SERVICES], timeout=60)
    return launch


@pytest.fixture(scope="module")
def layer_server(roscore, rospy_node, couchdb_server, tmp_path_factory):
    """A layer server with a fresh CouchDB database, a per-region topic for region floor_4 and
    fast markers. Yields (launch, db_url)."""
    db_url = couchdb_server.database_url("igmm_" + uuid.uuid4().hex[:10])
    params = server_params(db_url=db_url, marker_rate=10.0, regions=[
        {"region_id": "floor_4", "kind": "objects", "observation_topic": "/floor_4/objects"}])
    launch = start_server(roscore, tmp_path_factory.mktemp("igmm_server"), params)
    yield launch, db_url
    launch.stop()


@pytest.fixture
def start_layer_server(roscore, tmp_path):
    """start_layer_server(name, **param overrides) -> RosLaunch of one more server (stopped after)."""
    launches = []

    def start(name: str, **overrides) -> RosLaunch:
        launches.append(start_server(roscore, tmp_path / name, server_params(**overrides), name=name))
        return launches[-1]
    yield start
    for launch in launches:
        launch.stop()


@pytest.fixture(scope="module")
def observe(rospy_node):
    """observe(messages, topic=..., server="igmm_layers"): publish and wait until the server's
    received == applied + dropped counts include them; returns its LayerInfo afterwards."""
    publishers = {}

    def send(messages, topic: str = "/igmm_layers/observations", server: str = "igmm_layers",
             timeout: float = 60.0, expect_received: Optional[int] = None):
        info = rospy_node.ServiceProxy(f"/{server}/layer_info", LayerInfo)
        before = info().received
        if topic not in publishers:
            publishers[topic] = rospy_node.Publisher(topic, ObjectObservation, queue_size=20000)
        publisher = publishers[topic]
        wait_for_subscriber(publisher, f"/{server}", 90)
        for msg in messages:
            publisher.publish(msg)
        target = before + (len(messages) if expect_received is None else expect_received)

        def settled():
            now = info()
            return now if now.received >= target and now.received == now.applied + now.dropped else None
        return wait_until(settled, timeout, what=f"{server} to take in {len(messages)} observations")
    return send
