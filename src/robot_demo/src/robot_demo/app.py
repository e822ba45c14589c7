"""The workspace demo: every package's nodes shown working, chapter by chapter.

It starts a real roscore, a real database server and the nodes of every package, and exits by
itself unless --keep-running is given.

Chapters (robot_demo.chapters) run in order; one failing chapter is reported and the others still
run (exit status 1 at the end). Everything the demo started is stopped by process id on the way
out, and its output (plots, logs, the database) stays in --output.
"""
import argparse
import os
import signal
import socket
import threading
import time
from pathlib import Path
from typing import Dict, List, Optional, Tuple, Type, TypeVar

import rospkg
import rospy

from robot_common.params import NodeConfig
from robot_common.ros_node import shut_down_rospy
from robot_demo.chapters import (
    crowd_map,
    data_api,
    demonstrations,
    errands,
    fleet,
    object_layers,
    region_search,
    robot,
)
from robot_sim.params import load_config_file
from ros_harness import LaunchSet, ManagedProcess, PouchDBServer, RosCore, RosLaunch, free_port

__all__ = ["CHAPTERS", "Demo", "workspace_root", "parse_args", "main"]

ConfigT = TypeVar("ConfigT", bound=NodeConfig)

CHAPTERS = {module.__name__.rsplit(".", 1)[-1]: module for module in (
    robot, data_api, object_layers, region_search, crowd_map, demonstrations, fleet, errands)}


def workspace_root() -> Path:
    """The catkin workspace (its launch/ holds the composed launch files): $ROBOT_WS_ROOT, which
    env.sh sets, else the source tree this module lives in."""
    return Path(os.environ.get("ROBOT_WS_ROOT") or Path(__file__).resolve().parents[4])


class Demo:
    """What chapters share: the master, the database, the launches and the output folder."""

    def __init__(self, core: RosCore, db_server: PouchDBServer, output: Path):
        self.core = core
        self.db_server = db_server
        self.db_url = db_server.database_url("robot_data")
        self.output = output
        self.launches = LaunchSet(core, output / "logs")
        self.background: Dict[str, ManagedProcess] = {}
        # jobs a chapter's `prepare` queued to start later: set once each has ended
        self.queued: Dict[str, threading.Event] = {}

    def start_background(self, name: str, argv: List[str]) -> ManagedProcess:
        """Start a long job (e.g. training a model) now, beside the chapters; its output goes to
        logs/`name`.log. Stopped at the end if still running."""
        process = ManagedProcess(argv, name=name, log_path=self.output / "logs" / f"{name}.log")
        self.background[name] = process.start()
        return process

    def launch(self, package_or_path: str, launch_file: str = "", **args) -> RosLaunch:
        """Start `roslaunch package launch_file` (or a path) with `args`; stopped at the end."""
        return self.launches(package_or_path, launch_file, **args)

    def stop(self, launch: RosLaunch) -> None:
        """Stop one launch of this chapter (the others keep running)."""
        self.launches.stop(launch)

    def stop_all(self) -> None:
        self.launches.stop_all()
        for process in self.background.values():
            process.stop()

    @staticmethod
    def workspace_launch(name: str) -> str:
        """The path of a composed launch file in the workspace's launch/ folder."""
        return str(workspace_root() / "launch" / name)

    @staticmethod
    def sim_config(config_cls: Type[ConfigT], file_name: str) -> ConfigT:
        """A simulator's parameters as its launch file loads them (robot_sim config/`file_name`)."""
        path = Path(rospkg.RosPack().get_path("robot_sim")) / "config" / file_name
        return load_config_file(config_cls, path)


def say(text: str) -> None:
    print(text, flush=True)


def parse_args(argv: Optional[List[str]] = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="robot_demo", description=__doc__.splitlines()[0])
    parser.add_argument("--keep-running", action="store_true",
                        help="keep roscore, the database and the nodes up until Ctrl-C (for rviz)")
    parser.add_argument("--rviz", action="store_true", help="also start rviz (needs a display)")
    parser.add_argument("--port", type=int, default=11311,
                        help="roscore port (a free one is used if it is taken)")
    parser.add_argument("--output", type=Path, default=workspace_root() / "artifacts" / "demo",
                        help="folder for plots, screenshots, logs and the database")
    parser.add_argument("--only", nargs="*", choices=list(CHAPTERS), help="run only these chapters")
    return parser.parse_args(argv)


def main(argv: Optional[List[str]] = None) -> int:
    args = parse_args(argv)
    args.output.mkdir(parents=True, exist_ok=True)
    port = args.port if _port_free(args.port) else free_port()
    started = time.monotonic()
    core = RosCore(port=port, log_dir=args.output / "logs").start()
    os.environ.update(core.env())
    db_server = PouchDBServer(args.output / "couchdb").start()
    say(f"roscore:       {core.uri} (pid {core.process.pid})")
    say(f"CouchDB:       {db_server.url} (pouchdb-server, pid {db_server.process.pid}, "
        f"data in {db_server.data_dir})")
    demo = Demo(core, db_server, args.output)
    rospy.init_node("demo", anonymous=True, disable_signals=True)
    chapters_start = time.monotonic()
    failed, times = [], {}
    try:
        for name in args.only or CHAPTERS:     # long jobs of later chapters start now
            prepare = getattr(CHAPTERS[name], "prepare", None)
            if prepare is not None:
                prepare(demo)
        for name in args.only or CHAPTERS:
            succeeded, times[name] = _run_chapter(name, demo)
            if not succeeded:
                failed.append(name)
        say("\nchapter times: " + ", ".join(f"{name} {seconds:.0f} s" for name, seconds in times.items())
            + f" (setting up roscore and the database: {chapters_start - started:.0f} s)")
        if args.keep_running:
            keep_running(demo, args.rviz)
    finally:
        shut_down_rospy("demo finished")
        demo.stop_all()
        db_server.stop()
        core.stop()
    say(f"\ndemo {'failed in ' + ', '.join(failed) if failed else 'finished'} "
        f"in {time.monotonic() - started:.0f} s; output in {args.output}")
    return 1 if failed else 0


def _run_chapter(name: str, demo: Demo) -> Tuple[bool, float]:
    """Run one chapter: (False when it failed, the error printed; its seconds)."""
    chapter = CHAPTERS[name]
    say(f"\n=== {chapter.TITLE} ===")
    chapter_start = time.monotonic()
    try:
        chapter.run(demo)
        succeeded = True
    except Exception as err:  # noqa: BLE001 - report the chapter, go on with the others
        succeeded = False
        say(f"FAILED: {name}: {type(err).__name__}: {err}")
    seconds = time.monotonic() - chapter_start
    say(f"({name}: {seconds:.1f} s)")
    return succeeded, seconds


def keep_running(demo: Demo, with_rviz: bool) -> None:
    config = workspace_root() / "launch" / "demo.rviz"
    say(f"\nStill running. In another shell: source {workspace_root()}/env.sh && "
        f"export ROS_MASTER_URI={demo.core.uri} && rviz -d {config}")
    if with_rviz:
        demo.launches.node("rviz", "rviz", node_args=f"-d {config}")
    say("Press Ctrl-C to stop.")

    def interrupt(*_):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)
    try:
        while True:
            signal.pause()
    except KeyboardInterrupt:
        pass


def _port_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        return sock.connect_ex(("127.0.0.1", port)) != 0
