"""Fleet: three simulated robots record into their own stores and replicate to one central server;
the crowd model next to the central server learns from all three (ros_mongo, traffic_gp).

Each robot is what runs on a real one: its own roscore, its own store (pouchdb-server), the
recorder and the replicator of launch/fleet.launch, and simulated people counting (robot_sim
people_sim, one robot each, a different start hour each). The central side has its own roscore,
the central pouchdb-server and traffic_gp with ~source central (the central `_changes` feed).
Robot 2's link is cut for a while (its replicator's ~stop; recording goes on locally) and healed
(~start: the replication resumes from its checkpoint). The chapter then shows every message of
every robot central, and the crowd model's rows per robot.
"""
import shutil
import subprocess
from pathlib import Path
from typing import Dict, Tuple

import requests
import yaml

TITLE = "Fleet: three robots, one central server, the crowd model learns from all (ros_mongo, traffic_gp)"
SEED = 0
ROBOTS = ("robot1", "robot2", "robot3")
CUT = "robot2"          # the robot whose link is cut for a while
TOPIC = "/people_counts"
PEOPLE_TYPE = "robot_common/PeopleCount"
RATE = 4.0              # people counts per second per robot
RECORDED_BEFORE = 30    # counts each robot records before the cut
RECORDED_WHILE_CUT = 30  # counts the cut robot records while its link is down
LONG = 150.0            # seconds: roslaunch and TensorFlow start-up on a busy machine


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


class SimulatedRobot:
    """One robot: roscore, local store, fleet.launch (recorder + replicator), people_sim."""

    def __init__(self, robot_id: str, index: int, work: Path, central_url: str, map_yaml: Path,
                 fleet_launch: str):
        from ros_harness import LaunchSet, PouchDBServer, RosCore

        self.robot_id = robot_id
        self.work = work / robot_id
        self.core = RosCore(log_dir=self.work / "ros").start()
        self.store = PouchDBServer(self.work / "store").start()
        self.url = self.store.database_url("robot_data")
        self.launches = LaunchSet(self.core, self.work / "logs")
        self.fleet = self.launches(fleet_launch, central_url=central_url, robot_id=robot_id,
                                   local_db="true", local_db_server="false",
                                   local_db_port=self.store.port,
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

    def replication(self, action: str) -> str:
        """Call the replicator's ~start / ~stop."""
        ok, message = call_trigger(self.core, f"/ros_mongo_replicator/{action}")
        if not ok:
            raise RuntimeError(f"{self.robot_id} replication {action}: {message}")
        return message

    def recorded(self) -> int:
        return people_counts(self.url).get(self.robot_id, 0)

    def close(self) -> None:
        self.launches.stop_all()
        self.core.stop()
        self.store.stop()


def learned_rows(text: str) -> Dict[str, Tuple[int, int]]:
    """{robot: (rows, messages)} from traffic_gp's ~status message."""
    import re

    return {robot: (int(rows), int(count))
            for robot, rows, count in re.findall(r"(\w+): (\d+) rows from (\d+) messages", text)}


def run(demo) -> None:
    from robot_common.maps import save_map
    from robot_sim import generate_building
    from ros_harness import LaunchSet, PouchDBServer, RosCore, wait_until

    work = demo.output / "fleet"
    shutil.rmtree(work, ignore_errors=True)   # a fresh fleet each run: counts start at zero
    map_yaml = save_map(generate_building(SEED).grid, work / "map.yaml")
    central_core = RosCore(log_dir=work / "central" / "ros").start()
    central = PouchDBServer(work / "central" / "db").start()
    central_url = central.database_url("fleet")
    requests.put(central_url, timeout=30)
    central_launches = LaunchSet(central_core, work / "central" / "logs")
    robots = []
    try:
        print(f"  central: {central_url} (pouchdb-server), roscore {central_core.uri}")
        robots = [SimulatedRobot(robot_id, i, work, central_url, map_yaml,
                                 demo.workspace_launch("fleet.launch"))
                  for i, robot_id in enumerate(ROBOTS)]
        central_launches("traffic_gp", "traffic_gp.launch", map_yaml=str(map_yaml), source="central",
                         central_url=central_url, min_rows=1, initial_steps=20, n_inducing=32,
                         clock="observations", utc_offset_hours=0, publish_period=30.0)
        for robot in robots:
            robot.fleet.wait_for_subscribers([TOPIC], timeout=LONG)
            robot.start_counting()
            print(f"  {robot.robot_id}: store {robot.url}, roscore {robot.core.uri}, recording "
                  f"{TOPIC} and pushing it to central")
        wait_until(lambda: all(people_counts(central_url).get(r.robot_id, 0) >= RECORDED_BEFORE
                               for r in robots), LONG, interval=0.5,
                   what=f"{RECORDED_BEFORE} counts of every robot central")

        cut = next(r for r in robots if r.robot_id == CUT)
        print(f"  cutting {CUT}'s link: {cut.replication('stop')}")
        at_cut = cut.recorded()
        wait_until(lambda: cut.recorded() >= at_cut + RECORDED_WHILE_CUT, LONG, interval=0.5,
                   what=f"{CUT} to record {RECORDED_WHILE_CUT} counts while cut off")
        print(f"  while cut: {CUT} recorded {cut.recorded()} counts locally, central holds "
              f"{people_counts(central_url).get(CUT, 0)} of them (it had recorded {at_cut} at the "
              f"cut); the others' go on arriving: "
              + ", ".join(f"{r.robot_id} {people_counts(central_url).get(r.robot_id, 0)}"
                          for r in robots if r is not cut))
        for robot in robots:
            robot.stop_counting()
        print(f"  healing {CUT}'s link: {cut.replication('start')}")

        def all_central():
            local = {r.robot_id: r.recorded() for r in robots}
            return local if people_counts(central_url) == local else None
        recorded = wait_until(all_central, LONG, interval=0.5, what="every robot's counts central")
        print("  every message central, exactly once (robot: recorded locally = central):")
        for robot_id, count in recorded.items():
            print(f"    {robot_id}: {count} = {people_counts(central_url)[robot_id]}")

        def learned_all():
            ok, text = call_trigger(central_core, "/traffic_gp/status")
            rows = learned_rows(text)
            done = ok and {robot: messages for robot, (_, messages) in rows.items()} == recorded
            return text if done else None
        text = wait_until(learned_all, LONG, interval=2.0,
                          what="the crowd model to learn every robot's counts")
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
