"""Upload rules as users run them: `launch/fleet.launch upload_rules:=FILE` (the direct default)
on a robot's own roscore, recording into a central pouchdb-server. Odometry goes live, camera
images wait on the robot until a real `rostopic pub` says it is docked (std_msgs/Bool); the
recorder is restarted in the middle of the deferral; a local-only topic never reaches central; an
on_event topic reaches central only inside the window another node's trigger on ~event keeps.
The ledger command reads what the recorder saved, and it equals central's counts.
(The same core runs against the real Apache CouchDB in test_upload_rules.py.)"""
import shutil
import subprocess
import sys

import pytest
import requests
import yaml
from fleet_helpers import FleetRobot, all_docs, messages

from ros_harness import LaunchSet, ManagedProcess, PouchDBServer, RosCore, wait_until
from ros_mongo.errors import SpoolError
from ros_mongo.recording.ledger import read_ledger

LONG = 300.0
CAMERA = "/camera/rgb/image_raw"
RULES = """\
rules:
  - topics: ^/odom$
    upload: live
  - name: camera
    topics: ^/camera/
    upload: when
    when: {docked: /docked}
  - topics: ^/chatter$
    upload: local
  - name: blips
    topics: ^/blips$
    upload: on_event
    event: {before: 1.0, after: 0.5}
"""


def central_topics(admin_url):
    """Messages per topic in central (read as its admin)."""
    try:
        counts = {}
        for doc in messages(all_docs(admin_url)):
            counts[doc["topic"]] = counts.get(doc["topic"], 0) + 1
        return counts
    except (requests.RequestException, ValueError, KeyError):
        return {}


class RuledRobot(FleetRobot):
    def __init__(self, work, central_url, rules_file, workspace_root):
        self.robot_id, self.work = "robot1", work / "robot1"
        self.core = RosCore(log_dir=self.work / "ros").start()
        self.launches = LaunchSet(self.core, self.work / "launch")
        self.spool = self.work / "recorder.spool"
        self.args = dict(central_url=central_url, robot_id=self.robot_id, upload_rules=str(rules_file),
                         topics=f"[/odom, {CAMERA}, /chatter, /blips]", spool_path=str(self.spool))
        self.launch_file = str(workspace_root / "launch" / "fleet.launch")
        self.bag_tool = str(workspace_root / "src" / "ros_mongo" / "scripts" / "ros_mongo_bag")
        self.launch = self.launches(self.launch_file, **self.args)

    def restart(self):
        self.launches.stop(self.launch)
        self.launch = self.launches(self.launch_file, **self.args)
        self.launch.wait_for_subscribers(["/odom", CAMERA, "/docked"], timeout=LONG)

    def rostopic_pub(self, *argv):
        return ManagedProcess(["rostopic", "pub", *argv], name="rostopic pub",
                              log_path=self.work / f"pub{argv[0].replace('/', '_')}.log",
                              env=self.core.env()).start()

    def saved_ledger(self):
        """The ledger file as the recorder last saved it (every ~ledger_period, 5 s):
        [recorded, uploaded, dropped, recycled, waiting] per topic."""
        try:
            rows = read_ledger(str(self.spool) + ".ledger")
        except SpoolError:
            return {}
        return {topic: [int(row.get(k, 0)) for k in ("recorded", "uploaded", "dropped", "recycled",
                                                       "waiting")] for topic, row in rows.items()}

    def ledger(self):
        """The same, printed by `ros_mongo_bag ledger`."""
        result = subprocess.run([sys.executable, self.bag_tool, "ledger", str(self.spool)],
                                capture_output=True, text=True, env=self.core.env(), timeout=60)
        assert result.returncode == 0, result.stderr
        rows = [line.split() for line in result.stdout.splitlines()[1:]]
        # recorded, uploaded, dropped, recycled, waiting
        return {row[0]: [int(v) for v in row[1:6]] for row in rows}

    def trigger_event(self, request):
        """Call ~trigger_event (ros_mongo/TriggerEvent) as an operator would: its answer
        (`rosservice` run by this Python: it imports ros_mongo, whose libraries are in the venv)."""
        result = subprocess.run([sys.executable, shutil.which("rosservice"), "call",
                                 "/ros_mongo_server/trigger_event", request],
                                capture_output=True, text=True, env=self.core.env(), timeout=60)
        assert result.returncode == 0, result.stderr
        return yaml.safe_load(result.stdout)


@pytest.mark.ros
@pytest.mark.db
def test_fleet_launch_holds_images_until_docked_through_a_restart_and_keeps_local_topics(
        tmp_path, workspace_root):
    count, rate, hold = 120, 60.0, 60
    central = PouchDBServer(tmp_path / "central").start()
    admin_url = central.database_url("fleet")
    assert requests.put(admin_url, timeout=30).status_code == 201
    rules = tmp_path / "rules.yaml"
    rules.write_text(RULES)
    robot = RuledRobot(tmp_path, admin_url, rules, workspace_root)
    chatter = docked = blips = None
    try:
        robot.launch.wait_for_subscribers(["/odom", CAMERA, "/docked"], timeout=LONG)
        chatter = robot.rostopic_pub("/chatter", "std_msgs/String", "data: local only", "-r", "5")
        blips = robot.rostopic_pub("/blips", "std_msgs/String", "data: blip", "-r", "10")
        robot.publish(count, rate, hold_at=hold)
        wait_until(lambda: central_topics(admin_url).get("/odom", 0) == hold, LONG,
                   what=f"{hold} odometry messages central")
        robot.restart()  # in the middle of the deferral: the images wait in the robot's spool
        robot.go_file.touch()
        wait_until(lambda: central_topics(admin_url).get("/odom", 0) == count, LONG,
                   what="every odometry message central")
        wait_until(lambda: not robot.publisher.alive, LONG, what="everything published")
        assert robot.published() == {"/odom": count, CAMERA: count // 10}
        assert central_topics(admin_url) == {"/odom": count}   # no image, no /chatter, no /blips
        # another node triggers an event: /blips of [t - 1 s, t + 0.5 s] go up, labelled
        trigger = robot.rostopic_pub("/ros_mongo_server/event", "std_msgs/String", "data: bump", "-1")
        wait_until(lambda: central_topics(admin_url).get("/blips", 0) > 0, LONG, interval=0.5,
                   what="the event window")
        trigger.stop()
        # an operator's service call: its own reason and window, answered with the window kept
        refused = robot.trigger_event("{reason: typo, before: -1.0}")
        assert refused["success"] is False and "before" in refused["message"]
        answer = robot.trigger_event("{reason: operator, before: 0.5, after: 0.2}")
        assert answer["success"] is True and "blips: keeping" in answer["message"]
        span = [t["secs"] + t["nsecs"] * 1e-9 for t in (answer["start"], answer["end"])]
        assert span[1] - span[0] == pytest.approx(0.7, abs=1e-3)
        wait_until(lambda: any("event:operator" in d["tags"] for d in messages(all_docs(admin_url))),
                   LONG, interval=0.5, what="the operator's window")
        # the ledger is saved every ~ledger_period (5 s): the images wait on the robot
        wait_until(lambda: robot.saved_ledger().get(CAMERA, [0] * 5)[4] == count // 10, LONG,
                   interval=0.5, what="the ledger shows every image waiting")

        docked = robot.rostopic_pub("/docked", "std_msgs/Bool", "data: true", "-r", "2")
        wait_until(lambda: central_topics(admin_url).get(CAMERA, 0) == count // 10, LONG,
                   what="every image central after docking")
        docs = messages(all_docs(admin_url))
        blipped = [d for d in docs if d["topic"] == "/blips"]
        assert all({"event:bump", "event:operator"} & set(d["tags"]) for d in blipped)
        assert not any("event:typo" in d["tags"] for d in blipped)   # refused: nothing kept
        operator = [d["receive_time"] for d in blipped if "event:operator" in d["tags"]]
        assert span[0] <= min(operator) and max(operator) <= span[1]
        docs = [d for d in docs if d["topic"] != "/blips"]
        ids = [(d["topic"], int(d["msg"]["header"]["frame_id"])) for d in docs]
        assert len(ids) == len(set(ids)) == count + count // 10        # each message once
        assert {i for t, i in ids if t == CAMERA} == set(range(0, count, 10))
        assert "/chatter" not in {d["topic"] for d in docs}           # local never leaves
        want = {"/odom": [count, count, 0, 0, 0], CAMERA: [count // 10, count // 10, 0, 0, 0]}
        wait_until(lambda: {t: r for t, r in robot.saved_ledger().items() if t != "/blips"} == want
                   and robot.saved_ledger()["/blips"][1] == central_topics(admin_url)["/blips"],
                   LONG, interval=0.5, what=f"the ledger equal to central: {want}")
        printed = robot.ledger()
        assert {t: r for t, r in printed.items() if t != "/blips"} == want
        assert printed["/blips"][1] == central_topics(admin_url)["/blips"]
        assert printed["/blips"][3] > 0   # recycled: what no window kept
    finally:
        for process in (chatter, docked, blips):
            if process is not None:
                process.stop()
        robot.close()
        central.stop()
