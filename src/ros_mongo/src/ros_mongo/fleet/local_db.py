"""A local database server in the foreground (the ros_mongo_local_db executable; no ROS here).

The command lines come from robot_common.db_servers, which ros_harness uses too.
"""
import argparse
import re
import signal
import subprocess
import sys
from pathlib import Path
from typing import List, Optional

from robot_common.db_servers import KINDS, server_command

__all__ = ["main"]


def main(argv: Optional[List[str]] = None, *, default_data_dir: Path) -> int:
    """Run one server until SIGINT/SIGTERM, then stop it; 1 with one "ERROR: ..." line when it
    cannot start. `default_data_dir` is the --data-dir default (the executable passes
    $ROS_HOME/ros_mongo/db)."""
    argv = sys.argv[1:] if argv is None else argv
    argv = [a for a in argv if not re.match(r"^__\w+:=", a)]  # roslaunch's __name:= and __log:=
    parser = argparse.ArgumentParser(prog="ros_mongo_local_db", description=__doc__.splitlines()[0])
    parser.add_argument("--kind", choices=KINDS, default="couchdb")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=5984)
    parser.add_argument("--data-dir", type=Path, default=default_data_dir)
    args = parser.parse_args(argv)
    try:
        args.data_dir.mkdir(parents=True, exist_ok=True)
        command = server_command(args.kind, args.host, args.port, args.data_dir)
    except (OSError, ValueError) as err:
        print(f"ERROR: {err}", file=sys.stderr)
        return 1
    child = subprocess.Popen(command, cwd=str(args.data_dir))
    print(f"ros_mongo_local_db: {args.kind} on {args.host}:{args.port}, data in {args.data_dir} "
          f"(pid {child.pid})", flush=True)

    stopping = []

    def stop(*_):
        stopping.append(True)
        child.terminate()

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    try:
        status = child.wait()
        return 0 if stopping else status
    finally:
        if child.poll() is None:
            child.kill()
