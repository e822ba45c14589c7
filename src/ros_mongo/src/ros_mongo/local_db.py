"""A local database server process (pouchdb-server or nx-27017) for demos and trials."""
import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path
from typing import List, Optional

__all__ = ["server_command", "main"]


def server_command(kind: str, host: str, port: int, data_dir: Path) -> List[str]:
    """The command line that runs a local server of `kind` ("couchdb" or "mongodb")."""
    if kind == "couchdb":
        binary = os.environ.get("POUCHDB_SERVER_BIN") or shutil.which("pouchdb-server")
        if not binary or not Path(binary).exists():
            raise FileNotFoundError("pouchdb-server not found: set POUCHDB_SERVER_BIN or install it "
                                    "(npm install pouchdb-server@4.2.0)")
        # --unhandled-rejections=warn: one bad request must not end the server
        return ["node", "--unhandled-rejections=warn", binary, "-o", host, "-p", str(port),
                "-d", str(data_dir), "-c", str(data_dir / "config.json"), "-n"]
    if kind == "mongodb":
        binary = shutil.which("nx-27017")
        if not binary:
            raise FileNotFoundError("nx-27017 not found (pip install nx-27017)")
        return [binary, "--data-dir", str(data_dir), "--host", host, "-p", str(port),
                "--pid-file", str(data_dir / "nx-27017.pid"), "--log-file", str(data_dir / "nx-27017.log")]
    raise ValueError(f"unknown database kind {kind!r}: couchdb or mongodb")


def main(argv: Optional[List[str]] = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    argv = [a for a in argv if not re.match(r"^__\w+:=", a)]  # roslaunch's __name:= and __log:=
    parser = argparse.ArgumentParser(prog="ros_mongo_local_db", description=__doc__)
    parser.add_argument("--kind", choices=["couchdb", "mongodb"], default="couchdb")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=5984)
    parser.add_argument("--data-dir", type=Path,
                        default=Path(os.environ.get("ROS_HOME", Path.home() / ".ros")) / "ros_mongo" / "db")
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
