"""traffic_gp learning from the fleet: PeopleCount messages of three robots, each recorded in its own
store and pushed to a central CouchDB database by the store's replicator, read by the node from the
central `_changes` feed (~source central). Real processes: one pouchdb-server per robot plus the
central one, a roscore and the node through roslaunch. Expected counts come from what the test
recorded, never from the node.
"""
import json
import re
from pathlib import Path

import numpy as np
import pytest
import requests
import rospy
from geometry_msgs.msg import Point
from std_srvs.srv import Trigger

from robot_common.errors import ConfigError
from robot_common.maps import FREE, GridMap, save_map
from robot_common.msg import PeopleCount
from ros_harness import PouchDBServer, wait_until
from ros_mongo import open_store
from ros_mongo.fleet.replication import (
    CouchDatabase,
    PushReplication,
)
from traffic_gp.params import TrafficServerParams

NODE = "/traffic_gp"
LAUNCH = Path(__file__).resolve().parents[1] / "launch" / "traffic_gp.launch"
LONG = 150.0  # seconds: roslaunch and TensorFlow start-up on a busy machine
PEOPLE_TYPE = "robot_common/PeopleCount"


def people_count(robot_id: str, index: int, stamp: float):
    """A count over 1..3 cells (index % 3 + 1) of an all-free 10 m x 10 m map."""
    cells = [Point(1.25 + 0.5 * j, 1.25 + 0.5 * (index % 10), 0.0) for j in range(index % 3 + 1)]
    msg = PeopleCount(robot_id=robot_id, cells=cells, seen_fraction=[1.0] * len(cells),
                      counts=[(index + j) % 4 for j in range(len(cells))], duration=5.0)
    msg.header.stamp = rospy.Time.from_sec(stamp)
    return msg


class FleetRobot:
    """A robot's store with PeopleCount messages, pushed to central by the store's replicator."""

    def __init__(self, robot_id: str, work: Path, central_url: str):
        self.robot_id = robot_id
        self.server = PouchDBServer(work / robot_id).start()
        self.url = self.server.database_url("robot_data")
        self.store = open_store(self.url).connect()
        local = CouchDatabase(self.url)
        self.replication = PushReplication.for_robot(local, CouchDatabase(central_url), robot_id)
        self.recorded = [0, 0]  # rows, messages (rows: the cells of each message)
        self.next_index = 0

    def record(self, count: int, start_stamp: float) -> None:
        for _ in range(count):
            index = self.next_index
            msg = people_count(self.robot_id, index, start_stamp + 60.0 * index)
            self.store.insert_message("/people_counts", msg, robot_id=self.robot_id)
            self.recorded[0] += len(msg.cells)
            self.recorded[1] += 1
            self.next_index += 1

    def close(self) -> None:
        self.store.close()
        self.server.stop()


def central_people(central_url: str):
    """(PeopleCount documents per robot, sequence of the last one) read from central's feed."""
    answer = requests.get(central_url + "/_changes", params={"include_docs": "true"}, timeout=60)
    answer.raise_for_status()
    per_robot, last = {}, None
    for change in answer.json()["results"]:
        doc = change.get("doc") or {}
        if doc.get("kind") == "message" and doc.get("type") == PEOPLE_TYPE \
                and not change.get("deleted"):
            per_robot[doc["robot_id"]] = per_robot.get(doc["robot_id"], 0) + 1
            last = change["seq"]
    return per_robot, last


def learned(text: str):
    """{robot: (rows, messages)} as the node's status says it."""
    return {robot: (int(rows), int(count))
            for robot, rows, count in re.findall(r"(\w+): (\d+) rows from (\d+) messages", text)}


def test_source_central_needs_a_central_url():
    assert TrafficServerParams.from_mapping({}).source == "topic"
    config = TrafficServerParams.from_mapping({"source": "central", "central_url": "http://c:5984/fleet"})
    assert (config.source, config.central_url, config.central_topics) == (
        "central", "http://c:5984/fleet", [])
    with pytest.raises(ConfigError, match="central_url"):
        TrafficServerParams.from_mapping({"source": "central"})
    with pytest.raises(ConfigError, match="source"):
        TrafficServerParams.from_mapping({"source": "mesh"})
    with pytest.raises(ConfigError) as caught:
        TrafficServerParams.from_mapping({"source": "central", "central_url": "couch://u:hunter2@c/fleet"})
    assert "hunter2" not in str(caught.value)


@pytest.mark.ros
@pytest.mark.db
def test_learns_from_every_robot_through_central_and_resumes_after_a_restart(
        roslaunch, rospy_node, tmp_path):
    map_yaml = save_map(GridMap(np.full((40, 40), FREE), resolution=0.25), tmp_path / "map.yaml")
    model_path = tmp_path / "crowd.npz"
    central = PouchDBServer(tmp_path / "central").start()
    central_url = central.database_url("fleet")
    assert requests.put(central_url, timeout=30).status_code == 201
    robots = []
    try:
        robots = [FleetRobot(f"robot{i}", tmp_path, central_url) for i in (1, 2, 3)]
        stamp = 1_700_000_000.0
        for robot, count in zip(robots, (8, 10, 12)):
            robot.record(count, stamp)
            robot.replication.start()
        wanted = {r.robot_id: r.recorded[1] for r in robots}
        wait_until(lambda: central_people(central_url)[0] == wanted, LONG,
                   what="every robot's PeopleCount messages central")

        # a small GP on x, y with a few online steps after new rows: what the model learns is
        # the model tests' subject; here it is which rows reach it, and that a GP is saved
        def start_node():
            launch = roslaunch(str(LAUNCH), map_yaml=str(map_yaml), model_path=str(model_path),
                               min_rows=1, initial_steps=5, n_inducing=16, source="central",
                               central_url=central_url, publish_period=60.0,
                               model="{spatial_inputs: xy, online_steps: 5}")
            launch.wait_for_services([f"{NODE}/status", f"{NODE}/save_model"], timeout=LONG)
            return launch

        status = rospy.ServiceProxy(f"{NODE}/status", Trigger)

        def caught_up(expected):
            _, last_seq = central_people(central_url)
            text = status().message
            return learned(text) == expected and f"at sequence {last_seq}" in text

        launch = start_node()
        first = {r.robot_id: tuple(r.recorded) for r in robots}
        wait_until(lambda: caught_up(first), LONG, what="rows of all three robots learned")
        text = status().message
        assert "learned from 3 robots" in text
        assert f"model of {sum(rows for rows, _ in first.values())} rows" in text
        assert "central http://127.0.0.1" in text
        # the baselines serve at once; the GP is fitted in the background, and only a GP saves
        save = rospy.ServiceProxy(f"{NODE}/save_model", Trigger)
        saved = wait_until(lambda: (lambda r: r if r.success else None)(save()), 2 * LONG,
                           what="the GP fitted in the background, saved")
        assert saved.success, saved.message
        saved_learned = json.loads(Path(str(model_path) + ".learned.json").read_text())
        assert saved_learned["robots"] == {robot: list(counts) for robot, counts in first.items()}
        assert saved_learned["central"] == central_url and saved_learned["last_seq"] is not None
        roslaunch.stop(launch)

        # more counts while the node is down; the restarted node reads only those from the feed
        for robot in robots:
            robot.record(5, stamp + 86400.0)
        wanted = {r.robot_id: r.recorded[1] for r in robots}
        wait_until(lambda: central_people(central_url)[0] == wanted, LONG,
                   what="the new PeopleCount messages central")
        start_node()
        total = {r.robot_id: tuple(r.recorded) for r in robots}
        wait_until(lambda: caught_up(total), LONG, what="the new rows learned after the restart")
        text = status().message
        # the saved model's rows plus the new ones, each once (a replay from the feed's start
        # would count the first 30 messages twice)
        assert learned(text) == total
        assert f"model of {sum(rows for rows, _ in total.values())} rows" in text
    finally:
        for robot in robots:
            robot.close()
        central.stop()
