"""Learning from demonstrations recorded by any robot of a fleet: the central database holds each
robot's demonstrations (with its robot id, as the fleet's recorders store them); learn_reward takes
them all or those of some robots, and counts them per robot in its summary and the stored reward.
A real pouchdb-server database; expected counts are what the test stored."""
import subprocess
import sys
import uuid
from pathlib import Path

import pytest
import rospy
import yaml

from lfd_controller import ros_demos
from lfd_controller.errors import DemonstrationError
from lfd_controller.learn_reward import demos_per_robot, learn_from_sources, load_sources
from ros_mongo import open_store

LEARN_REWARD = Path(__file__).resolve().parents[1] / "nodes" / "learn_reward"
RECORDED = {"robot1": 2, "robot2": 3, "robot3": 1}  # demonstrations each robot recorded


@pytest.fixture
def central_url(couchdb_server, expert_demos):
    """A fresh central database with RECORDED demonstrations per robot (six expert demos)."""
    url = couchdb_server.database_url("fleet_" + uuid.uuid4().hex[:10])
    demos = iter(expert_demos)
    with open_store(url) as store:
        for robot, count in RECORDED.items():
            for _ in range(count):
                msg = ros_demos.to_msg(next(demos), rospy.Time.from_sec(1_700_000_000.0))
                store.insert_message(ros_demos.DEMO_TOPIC, msg, robot_id=robot,
                                     tags=["demonstration", msg.scenario_name, msg.source],
                                     receive_time=msg.header.stamp.to_sec())
    return url


@pytest.mark.db
def test_demonstrations_of_every_robot_or_of_some_come_with_their_robot(central_url):
    everyone = load_sources([], central_url)
    assert demos_per_robot(everyone) == RECORDED
    some = load_sources([], central_url, robot_ids=["robot1", "robot3"])
    assert demos_per_robot(some) == {"robot1": 2, "robot3": 1}
    assert demos_per_robot(load_sources([], central_url, scenario="static_obstacle",
                                        robot_ids=["robot2"])) == {"robot2": 3}
    with pytest.raises(DemonstrationError, match="recorded by robot9"):
        load_sources([], central_url, robot_ids=["robot9"])


@pytest.mark.db
def test_learned_reward_counts_the_demonstrations_per_robot(central_url, tmp_path):
    summary = learn_from_sources([], central_url, robot_ids=["robot2", "robot3"],
                                 output=str(tmp_path / "reward.yaml"), store_db=True)
    assert summary.splitlines()[-1] == "demonstrations per robot: robot2: 3, robot3: 1"
    with open_store(central_url) as store:
        stored = list(store.find_messages(topic=ros_demos.REWARD_TOPIC))
    assert len(stored) == 1
    info = yaml.safe_load(stored[0].message().data)["info"]
    assert info["demonstrations_per_robot"] == {"robot2": 3, "robot3": 1}
    assert info["demonstrations"] == 4


@pytest.mark.db
def test_learn_reward_command_line_takes_robot_ids(central_url, tmp_path):
    done = subprocess.run(
        [sys.executable, str(LEARN_REWARD), "--db-url", central_url, "--robot-ids", "robot1",
         "robot2", "--output", str(tmp_path / "reward.yaml")],
        capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "demonstrations per robot: robot1: 2, robot2: 3"
    assert (tmp_path / "reward.yaml").exists()
