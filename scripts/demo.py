#!/usr/bin/env python3
"""The workspace demo (`make demo`): a real roscore, a real database server and the nodes of every
package, shown working chapter by chapter; it exits by itself unless --keep-running is given.

Each chapter is a module in scripts/demo_chapters/ with `TITLE` and `run(demo)`; `demo` is the
`Demo` below (roscore, database, launches, output folder). Chapters print what they show.
"""
import argparse
import importlib
import os
import signal
import sys
import time
from pathlib import Path
from typing import List, Optional

from ros_harness import PouchDBServer, RosCore, RosLaunch, free_port

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))

CHAPTERS = ["robot", "data_api", "object_layers", "region_search", "crowd_map", "demonstrations"]


class Demo:
    """What chapters share: the master, the database, launches and the output folder."""

    def __init__(self, core: RosCore, db_server: PouchDBServer, output: Path):
        self.core = core
        self.db_server = db_server
        self.db_url = db_server.database_url("robot_data")
        self.output = output
        self.launches: List[RosLaunch] = []

    def launch(self, package_or_path: str, launch_file: str = "", **args) -> RosLaunch:
        target = [package_or_path, launch_file] if launch_file else [package_or_path]
        launch = RosLaunch(target, master_uri=self.core.uri, log_dir=self.output / "logs",
                           args=args, env=self.core.env())
        self.launches.append(launch)
        return launch.start()

    def stop(self, launch: RosLaunch) -> None:
        """Stop one launch of this chapter (the others keep running)."""
        launch.stop()
        self.launches.remove(launch)

    def stop_all(self) -> None:
        for launch in reversed(self.launches):
            launch.stop()
        self.launches.clear()


def say(text: str) -> None:
    print(text, flush=True)


def parse_args(argv: Optional[List[str]] = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep-running", action="store_true",
                        help="keep roscore, the database and the nodes up until Ctrl-C (for rviz)")
    parser.add_argument("--rviz", action="store_true", help="also start rviz (needs a display)")
    parser.add_argument("--port", type=int, default=11311,
                        help="roscore port (a free one is used if it is taken)")
    parser.add_argument("--output", type=Path, default=ROOT / "artifacts" / "demo",
                        help="folder for plots, screenshots, logs and the database")
    parser.add_argument("--only", nargs="*", choices=CHAPTERS, help="run only these chapters")
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
    import rospy

    rospy.init_node("demo", anonymous=True, disable_signals=True)
    failed = []
    try:
        for name in args.only or CHAPTERS:
            try:
                chapter = importlib.import_module(f"demo_chapters.{name}")
            except ModuleNotFoundError as err:
                if err.name != f"demo_chapters.{name}":
                    raise
                continue
            say(f"\n=== {chapter.TITLE} ===")
            chapter_start = time.monotonic()
            try:
                chapter.run(demo)
            except Exception as err:  # noqa: BLE001 - report the chapter, go on with the others
                failed.append(name)
                say(f"FAILED: {name}: {type(err).__name__}: {err}")
            say(f"({time.monotonic() - chapter_start:.1f} s)")
        if args.keep_running:
            keep_running(demo, args.rviz)
    finally:
        rospy.signal_shutdown("demo finished")
        demo.stop_all()
        db_server.stop()
        core.stop()
    say(f"\ndemo {'failed in ' + ', '.join(failed) if failed else 'finished'} "
        f"in {time.monotonic() - started:.0f} s; output in {args.output}")
    return 1 if failed else 0


def keep_running(demo: Demo, with_rviz: bool) -> None:
    config = ROOT / "launch" / "demo.rviz"
    say(f"\nStill running. In another shell: source {ROOT}/env.sh && "
        f"export ROS_MASTER_URI={demo.core.uri} && rviz -d {config}")
    if with_rviz:
        demo.launches.append(RosLaunch.node("rviz", "rviz", master_uri=demo.core.uri,
                                            log_dir=demo.output / "logs", env=demo.core.env(),
                                            node_args=f"-d {config}").start())
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
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        return sock.connect_ex(("127.0.0.1", port)) != 0


if __name__ == "__main__":
    sys.exit(main())
