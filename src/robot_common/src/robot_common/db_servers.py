"""Local database servers: the one place their command lines are built (no ROS).

CouchDB API: pouchdb-server (npm; $POUCHDB_SERVER_BIN, else on PATH), run by node with
`--unhandled-rejections=warn` (without it one bad request can end the server). MongoDB wire
protocol: nx-27017 (PyPI; $NX27017_BIN, else on PATH). Each server keeps its PID file and log apart
from the others', so several can run at once. A missing program raises FileNotFoundError naming
how to get it. Used by ros_mongo's `ros_mongo_local_db` (a robot's local store) and by ros_harness
(servers for tests, the demo and benchmarks).
"""
import os
import shutil
from pathlib import Path
from typing import List, Optional

__all__ = ["KINDS", "couchdb_server_command", "mongodb_server_command", "server_command"]

KINDS = ("couchdb", "mongodb")


def _program(env_var: str, program: str, hint: str) -> str:
    path = os.environ.get(env_var) or shutil.which(program)
    if not path or not Path(path).exists():
        raise FileNotFoundError(f"{program} not found: set {env_var} or {hint}")
    return path


def couchdb_server_command(*, port: int, data_dir: Path, host: str = "127.0.0.1",
                           in_memory: bool = False) -> List[str]:
    """pouchdb-server on `host`:`port`, its databases, config.json and log in `data_dir`
    (databases in memory instead when `in_memory`: gone when it stops)."""
    binary = _program("POUCHDB_SERVER_BIN", "pouchdb-server",
                      "run scripts/setup.sh (npm install pouchdb-server@4.2.0)")
    data_dir = Path(data_dir)
    command = ["node", "--unhandled-rejections=warn", binary, "-o", host, "-p", str(port),
               "-d", str(data_dir), "-c", str(data_dir / "config.json"), "-n"]
    return command + (["-m"] if in_memory else [])


def mongodb_server_command(*, port: int, data_dir: Optional[Path], host: str = "127.0.0.1",
                           pid_file: Optional[Path] = None, log_file: Optional[Path] = None,
                           in_memory: bool = False) -> List[str]:
    """nx-27017 on `host`:`port`: one SQLite file per database in `data_dir` (isolated in-memory
    databases instead when `in_memory`, and then `data_dir` may be None).

    The PID file and log default to nx-27017.pid / nx-27017.log in `data_dir` (the log beside
    `pid_file` when only that is given). nx-27017's own defaults are shared by every server on the
    machine, so without `data_dir` a `pid_file` is required (ValueError).
    """
    if data_dir is None and not in_memory:
        raise ValueError("nx-27017 needs a data_dir unless in_memory")
    if pid_file is None:
        if data_dir is None:
            raise ValueError("nx-27017 needs a pid_file of its own when it has no data_dir")
        pid_file = Path(data_dir) / "nx-27017.pid"
    if log_file is None:
        log_file = Path(data_dir) / "nx-27017.log" if data_dir is not None \
            else Path(pid_file).with_suffix(".log")
    binary = _program("NX27017_BIN", "nx-27017", "run scripts/setup.sh (pip install nx-27017)")
    return [binary, "--data-dir", "memory" if in_memory else str(data_dir), "--host", host,
            "-p", str(port), "--pid-file", str(pid_file), "--log-file", str(log_file)]


def server_command(kind: str, host: str, port: int, data_dir: Path) -> List[str]:
    """The command line of a local server of `kind` ("couchdb" or "mongodb") keeping its data
    in `data_dir`."""
    if kind == "couchdb":
        return couchdb_server_command(port=port, data_dir=data_dir, host=host)
    if kind == "mongodb":
        return mongodb_server_command(port=port, data_dir=data_dir, host=host)
    raise ValueError(f"unknown database kind {kind!r}: {' or '.join(KINDS)}")
