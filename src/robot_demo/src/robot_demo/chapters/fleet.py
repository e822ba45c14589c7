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
each robot's recorder received, and the crowd model's rows per robot.
"""
import re
import shutil
import subprocess
from pathlib import Path
from typing import Dict, Tuple

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


def call_trigger(core, service: str, timeout: float = 60.0) -> Tuple[bool, str]:
    """Call a std_srvs/Trigger service on another roscore (`rosservice call`): (success, message)."""
    done = subprocess.run(["rosservice", "call", service], env=core.env(), capture_output=True,
                          text=True, timeout=timeout)
    if done.returncode != 0:
        raise RuntimeError(f"rosservice call {service}: {done.stderr.strip() or done.stdout.strip()}")
    answer = yaml.safe_load(done.stdout) or {}
    return bool(answer.get("success")), str(answer.get("message", ""))


def people_counts(db_url: str) -> Dict[str, int]:
    """PeopleCount message documents per robot id in a database (read over HTTP)."""
    answer = requests.get(db_url + "/_all_docs", params={"include_docs": "true"}, timeout=60)
    if answer.status_code == 404:
        return {}
    answer.raise_for_status()
    counts: Dict[str, int] = {}
    for row in answer.json()["rows"]:
        doc = row.get("doc") or {}
        if doc.get("kind") == "message" and doc.get("type") == PEOPLE_TYPE:
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
                 fleet_launch: str):
        from ros_harness import LaunchSet, RosCore

        self.robot_id = robot_id
        self.work = work / robot_id
        self.core = RosCore(log_dir=self.work / "ros").start()
        self.launches = LaunchSet(self.core, self.work / "logs")
        self.fleet = self.launches(fleet_launch, central_url=central_url, robot_id=robot_id,
                                   topics=f"[{TOPIC}]", spool_path=str(self.work / "recorder.spool"))
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
        """received, stored and spool_pending of the robot's recorder."""
        values = recorder_values(self.core)
        return {key: int(values[key]) for key in ("received", "stored", "spool_pending")}

    def close(self) -> None:
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
        robots = [SimulatedRobot(robot_id, i, work, central_url, map_yaml,
                                 demo.workspace_launch("fleet.launch"))
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
        waits.wait_until(lambda: all(people_counts(central_url).get(r.robot_id, 0) >= RECORDED_BEFORE
                                     for r in robots), 240,
                         f"{RECORDED_BEFORE} counts of every robot central", interval=0.5)

        outage(central, robots, central_url)

        for robot in robots:
            robot.stop_counting()

        def all_central():
            states = {r.robot_id: r.recorder() for r in robots}
            done = all(s["spool_pending"] == 0 and s["stored"] == s["received"]
                       for s in states.values())
            received = {robot_id: s["received"] for robot_id, s in states.items()}
            return received if done and people_counts(central_url) == received else None
        recorded = waits.wait_until(all_central, 240, "every robot's spool drained and every count central",
                                    interval=1.0)
        print("  every message central, exactly once (robot: received by its recorder = central):")
        central_counts = people_counts(central_url)
        for robot_id, count in recorded.items():
            print(f"    {robot_id}: {count} = {central_counts[robot_id]}")

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
