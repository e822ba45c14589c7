"""Fleet: three simulated robots record straight to one central server, which goes down for a while;
the crowd model next to the central server learns from all three (ros_mongo, traffic_gp).

Each robot is what runs on a real one with the fleet default (launch/fleet.launch): its own
roscore, the recorder writing straight to the central CouchDB database with its spool on the
robot's disk as the only buffer (no database server on the robot), and simulated people counting
(robot_sim people_sim, one robot each, a different start hour each). The central side has its own
roscore, the central pouchdb-server and traffic_gp with ~source central (the central `_changes`
feed), with a small, quick model (no hold-out days) so that the chapter takes a minute.
Central is stopped while the robots go on counting (each recorder spools) and started again (the
spools drain, in order, each message once). The chapter then shows that central holds exactly what
each robot's recorder received, and the crowd model's rows per robot. robot1 also has upload rules
(UPLOAD_RULES): its /snapshots wait on its disk until it docks (std_msgs/Bool /docked), and its
/bumper goes up only inside the window an event keeps (~event, from another node).
"""
import re
import shutil
import subprocess
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import requests
import yaml

from robot_demo import waits

TITLE = ("Fleet: three robots straight to one central server through an outage; the crowd model "
         "learns from all (ros_mongo, traffic_gp)")
SEED = 0
ROBOTS = ("robot1", "robot2", "robot3")
TOPIC = "/people_counts"
PEOPLE_TYPE = "robot_common/PeopleCount"
RATE = 4.0              # people counts per second per robot
RECORDED_BEFORE = 30    # counts of each robot central before the outage
RECORDED_WHILE_DOWN = 20  # counts each robot records (spools) while central is down
RECORDER = "ros_mongo_server: recorder"
QUICK_MODEL = "{validation_fraction: 0.0}"
UPLOAD_RULES = """\
rules:
  - name: snapshots
    topics: ^/snapshots$
    upload: when
    when: {docked: /docked}
  - name: bumper
    topics: ^/bumper$
    upload: on_event
    event: {before: 1.0, after: 0.5}
default: live
"""


def call_trigger(core, service: str, timeout: float = 60.0) -> Tuple[bool, str]:
    """Call a std_srvs/Trigger service on another roscore (`rosservice call`): (success, message)."""
    done = subprocess.run(["rosservice", "call", service], env=core.env(), capture_output=True,
                          text=True, timeout=timeout)
    if done.returncode != 0:
        raise RuntimeError(f"rosservice call {service}: {done.stderr.strip() or done.stdout.strip()}")
    answer = yaml.safe_load(done.stdout) or {}
    return bool(answer.get("success")), str(answer.get("message", ""))


def message_docs(db_url: str) -> List[dict]:
    """Every message document of a database (read over HTTP)."""
    answer = requests.get(db_url + "/_all_docs", params={"include_docs": "true"}, timeout=60)
    if answer.status_code == 404:
        return []
    answer.raise_for_status()
    return [row["doc"] for row in answer.json()["rows"]
            if (row.get("doc") or {}).get("kind") == "message"]


def people_counts(db_url: str) -> Dict[str, int]:
    """PeopleCount message documents per robot id in a database."""
    counts: Dict[str, int] = {}
    for doc in message_docs(db_url):
        if doc.get("type") == PEOPLE_TYPE:
            counts[doc.get("robot_id")] = counts.get(doc.get("robot_id"), 0) + 1
    return counts


def recorder_values(core, timeout: float = 60.0) -> Dict[str, str]:
    """The recorder's latest /diagnostics values on a robot's roscore (`rostopic echo -n 1`)."""
    done = subprocess.run(["rostopic", "echo", "-n", "1", "/diagnostics"], env=core.env(),
                          capture_output=True, text=True, timeout=timeout)
    if done.returncode != 0:
        raise RuntimeError(f"rostopic echo /diagnostics: {done.stderr.strip()}")
    message = yaml.safe_load(done.stdout.split("\n---")[0]) or {}
    for status in message.get("status") or []:
        if status.get("name") == RECORDER:
            return {str(kv["key"]): str(kv["value"]) for kv in status.get("values") or []}
    return {}


class SimulatedRobot:
    """One robot: roscore, fleet.launch in its default form (recorder + spool), people_sim."""

    def __init__(self, robot_id: str, index: int, work: Path, central_url: str, map_yaml: Path,
                 fleet_launch: str, rules: Optional[Path] = None):
        from ros_harness import LaunchSet, RosCore

        self.robot_id = robot_id
        self.work = work / robot_id
        self.core = RosCore(log_dir=self.work / "ros").start()
        self.launches = LaunchSet(self.core, self.work / "logs")
        extra = dict(upload_rules=str(rules)) if rules else {}
        topics = f"[{TOPIC}, /snapshots, /bumper]" if rules else f"[{TOPIC}]"
        self.fleet = self.launches(fleet_launch, central_url=central_url, robot_id=robot_id,
                                   topics=topics, spool_path=str(self.work / "recorder.spool"), **extra)
        self.extras: List = []
        self.index = index
        self.map_yaml = map_yaml
        self.sim = None

    def start_counting(self) -> None:
        """Simulated people counting (one robot, its own hours of the week)."""
        self.sim = self.launches("robot_sim", "people_sim.launch", map_yaml=str(self.map_yaml),
                                 seed=SEED, robots=1, rate=RATE, time_scale=600.0,
                                 start_hour=48.0 + 8.0 + 3.0 * self.index)

    def stop_counting(self) -> None:
        if self.sim is not None:
            self.launches.stop(self.sim)
            self.sim = None

    def recorder(self) -> Dict[str, int]:
        """received (people counts), stored and spool_pending of the robot's recorder."""
        values = recorder_values(self.core)
        return {"received": int(values.get(f"topic {TOPIC}", 0)), "stored": int(values["stored"]),
                "spool_pending": int(values["spool_pending"])}

    def rostopic_pub(self, *argv: str):
        """A real `rostopic pub` on this robot's roscore (stopped with the robot)."""
        from ros_harness import ManagedProcess

        process = ManagedProcess(["rostopic", "pub", *argv], name=f"rostopic pub {argv[0]}",
                                 log_path=self.work / f"pub{argv[0].replace('/', '_')}.log",
                                 env=self.core.env()).start()
        self.extras.append(process)
        return process

    def close(self) -> None:
        for process in self.extras:
            process.stop()
        self.launches.stop_all()
        self.core.stop()


def learned_rows(text: str) -> Dict[str, Tuple[int, int]]:
    """{robot: (rows, messages)} from traffic_gp's ~status message."""
    return {robot: (int(rows), int(count))
            for robot, rows, count in re.findall(r"(\w+): (\d+) rows from (\d+) messages", text)}


def run(demo) -> None:
    from robot_common.maps import save_map
    from robot_sim import generate_building
    from ros_harness import LaunchSet, PouchDBServer, RosCore

    work = demo.output / "fleet"
    shutil.rmtree(work, ignore_errors=True)   # a fresh fleet each run: counts start at zero
    map_yaml = save_map(generate_building(SEED).grid, work / "map.yaml")
    central_core = RosCore(log_dir=work / "central" / "ros").start()
    central = PouchDBServer(work / "central" / "db").start()
    central_url = central.database_url("fleet")
    requests.put(central_url, timeout=30)     # an admin creates the fleet's database once
    central_launches = LaunchSet(central_core, work / "central" / "logs")
    robots = []
    try:
        print(f"  central: {central_url} (pouchdb-server), roscore {central_core.uri}")
        rules = work / "robot1_upload_rules.yaml"
        rules.write_text(UPLOAD_RULES)
        robots = [SimulatedRobot(robot_id, i, work, central_url, map_yaml,
                                 demo.workspace_launch("fleet.launch"), rules if i == 0 else None)
                  for i, robot_id in enumerate(ROBOTS)]
        central_launches("traffic_gp", "traffic_gp.launch", map_yaml=str(map_yaml), source="central",
                         central_url=central_url, min_rows=1, initial_steps=20, n_inducing=32,
                         model=QUICK_MODEL, clock="observations", utc_offset_hours=0,
                         publish_period=30.0)
        print(f"  crowd model: traffic_gp ~source central, a small quick model {QUICK_MODEL} "
              "(the node's default is the full model)")
        for robot in robots:
            waits.subscribers(robot.fleet, [TOPIC], 240)
            robot.start_counting()
            print(f"  {robot.robot_id}: roscore {robot.core.uri}, recording {TOPIC} straight to "
                  f"central, spool {robot.work / 'recorder.spool'}")
        snapshots = robots[0].rostopic_pub("/snapshots", "std_msgs/String", "data: snapshot", "-r", "2")
        robots[0].rostopic_pub("/bumper", "std_msgs/String", "data: bump", "-r", "10")
        print("  robot1 also records /snapshots (upload: when docked) and /bumper (upload: on_event, "
              "1 s before and 0.5 s after an event)")
        waits.wait_until(lambda: all(people_counts(central_url).get(r.robot_id, 0) >= RECORDED_BEFORE
                                     for r in robots), 240,
                         f"{RECORDED_BEFORE} counts of every robot central", interval=0.5)
        robots[0].rostopic_pub("/ros_mongo_server/event", "std_msgs/String", "data: door opened", "-1")

        outage(central, robots, central_url)

        for robot in robots:
            robot.stop_counting()

        def all_central():
            states = {r.robot_id: r.recorder() for r in robots}
            done = all(s["spool_pending"] == 0 for s in states.values())
            received = {robot_id: s["received"] for robot_id, s in states.items()}
            return received if done and people_counts(central_url) == received else None
        recorded = waits.wait_until(all_central, 240, "every robot's spool drained and every count central",
                                    interval=1.0)
        print("  every message central, exactly once (robot: received by its recorder = central):")
        central_counts = people_counts(central_url)
        for robot_id, count in recorded.items():
            print(f"    {robot_id}: {count} = {central_counts[robot_id]}")
        snapshots.stop()
        docking(robots[0], central_url)

        def learned_all():
            ok, text = call_trigger(central_core, "/traffic_gp/status")
            rows = learned_rows(text)
            done = ok and {robot: messages for robot, (_, messages) in rows.items()} == recorded
            return text if done else None
        text = waits.wait_until(learned_all, 240, "the crowd model to learn every robot's counts",
                                interval=2.0)
        print("  crowd model (traffic_gp, ~source central), rows and messages learned per robot:")
        for robot_id, (rows, count) in learned_rows(text).items():
            print(f"    {robot_id}: {rows} rows from {count} messages")
        print(f"  status: {text}")
    finally:
        for robot in robots:
            robot.close()
        central_launches.stop_all()
        central.stop()
        central_core.stop()


def outage(central, robots, central_url: str) -> None:
    """Stop central while the robots count, until each has spooled some counts; start it again."""
    before = people_counts(central_url)
    at_stop = {r.robot_id: r.recorder()["received"] for r in robots}
    central.stop()
    print(f"  central stopped (an outage): it holds {sum(before.values())} counts "
          f"({', '.join(f'{k} {v}' for k, v in sorted(before.items()))})")

    def spooled():
        states = {r.robot_id: r.recorder() for r in robots}
        return states if all(s["received"] >= at_stop[robot_id] + RECORDED_WHILE_DOWN
                             and s["spool_pending"] > 0
                             for robot_id, s in states.items()) else None
    states = waits.wait_until(spooled, 240,
                              f"every robot to record {RECORDED_WHILE_DOWN} counts into its spool "
                              "while central is down", interval=1.0)
    print("  while central was down: " + ", ".join(
        f"{robot_id} received {s['received']}, {s['spool_pending']} waiting in its spool"
        for robot_id, s in states.items()))
    central.start()
    print(f"  central started again on the same port and data: {central.url}")


def docking(robot: SimulatedRobot, central_url: str) -> None:
    """robot1's deferred /snapshots: none central until it docks, then every one, once; and the
    /bumper window its event kept."""
    def topic_docs(topic):
        return [d for d in message_docs(central_url) if d.get("topic") == topic]

    print(f"  robot1 undocked: {len(topic_docs('/snapshots'))} /snapshots central (they wait on its disk)")
    robot.rostopic_pub("/docked", "std_msgs/Bool", "data: true", "-r", "2")

    def all_snapshots():
        values = recorder_values(robot.core)
        recorded = int(values.get("topic /snapshots", 0))
        return values if len(topic_docs("/snapshots")) >= recorded > 0 else None
    values = waits.wait_until(all_snapshots, 120, "robot1's snapshots central after docking",
                              interval=0.5)
    stamps = [d["_id"] for d in topic_docs("/snapshots")]
    print(f"  robot1 docked (/docked true): {len(stamps)} of {values['topic /snapshots']} /snapshots "
          f"recorded are central, {len(stamps) - len(set(stamps))} twice")
    window = waits.wait_until(lambda: topic_docs("/bumper") or None, 120, "robot1's event window central",
                              interval=0.5)
    labels = sorted({tag for d in window for tag in d.get("tags", []) if tag.startswith("event:")})
    print(f"  robot1's event window: {len(window)} /bumper messages central, labelled {labels}; "
          f"ledger /bumper: {values.get('ledger /bumper', 'not saved yet')}")
