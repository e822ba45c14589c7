"""The demo's fleet chapter, run as a user runs it (`python -m robot_demo --only fleet`): three
simulated robots and a central server, one link cut and healed. Afterwards each robot's store and
the central store are opened again (real pouchdb-servers on the chapter's data) and counted here:
central holds exactly what each robot recorded, and the crowd model learned every robot's counts.
"""
import re
import subprocess
import sys

import pytest

from robot_demo.chapters.fleet import ROBOTS, people_counts
from ros_harness import PouchDBServer, free_port


@pytest.mark.slow
@pytest.mark.ros
@pytest.mark.db
def test_fleet_chapter_brings_every_robots_counts_central_and_into_the_crowd_model(tmp_path):
    done = subprocess.run([sys.executable, "-m", "robot_demo", "--only", "fleet", "--output",
                           str(tmp_path), "--port", str(free_port())],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    out = done.stdout
    assert "cutting robot2's link" in out and "healing robot2's link" in out
    recorded = {}
    for robot_id in ROBOTS:
        with PouchDBServer(tmp_path / "fleet" / robot_id / "store") as store:
            recorded[robot_id] = people_counts(store.database_url("robot_data"))[robot_id]
    with PouchDBServer(tmp_path / "fleet" / "central" / "db") as central:
        assert people_counts(central.database_url("fleet")) == recorded
    # the cut robot went on recording while cut off: more than the 30 counts before the cut
    assert recorded["robot2"] >= 60
    shown = {robot: int(count) for robot, count in re.findall(r"(robot\d): (\d+) = \d+", out)}
    assert shown == recorded
    learned = {robot: int(count) for robot, count in
               re.findall(r"(robot\d): \d+ rows from (\d+) messages", out.split("status:")[0])}
    assert learned == recorded
