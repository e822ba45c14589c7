"""A real Apache CouchDB 3 node and a real 3-node cluster, from a release folder beside the clone.

The release (`couchdb-release.tar.gz`) and its scripts (`couchdb-node.sh`, `couchdb-cluster.sh`) live
in `<workspace>/../shared/couchdb` (or `$SHARED_COUCHDB_DIR`); `shared_couchdb_dir()` finds them and
says why not when they are absent (a user's clone has no ../shared). Nothing is written there: each
copy unpacks into its own work folder (a test's tmp dir) and keeps its data, log and pid there.

Each copy listens on free ports of 127.0.0.1 (HTTP, Erlang distribution = HTTP + 1000) with its own
epmd on a free port (`ERL_EPMD_PORT`), so copies of parallel test workers never share an Erlang
name service, and the scripts' `stop DIR` ends exactly that copy's processes by pid (and its epmd).
Accounts: a server admin (the test's own steps: creating databases, `_security`, users) and a
database *member* (what the product under test talks as); random passwords, never logged.
"""
import hashlib
import json
import os
import random
import secrets
import signal
import socket
import subprocess
import urllib.error
import urllib.request
from base64 import b64encode
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple
from urllib.parse import quote

from ros_harness.errors import HarnessError
from ros_harness.processes import START_TIMEOUT, STOP_TIMEOUT, wait_until

__all__ = ["shared_couchdb_dir", "missing_reason", "ApacheCouchDB", "CouchDBCluster", "beam_cpu_seconds"]

NODE_SCRIPT = "couchdb-node.sh"
CLUSTER_SCRIPT = "couchdb-cluster.sh"
TARBALL = "couchdb-release.tar.gz"
MEMBER = "robot"
_HASH_ITERATIONS = 10_000  # the admin's pbkdf2 hash (test servers only; CouchDB's default is 600,000)
#: Erlang VM flags (ERL_AFLAGS) of the copies: no busy waiting of idle schedulers.
IDLE_SCHEDULERS_SLEEP = "+sbwt none +sbwtdcpu none +sbwtdio none"


def shared_couchdb_dir(workspace_root: Path) -> Path:
    """`$SHARED_COUCHDB_DIR` or `<workspace_root>/../shared/couchdb` (it may not exist)."""
    given = os.environ.get("SHARED_COUCHDB_DIR")
    return Path(given) if given else Path(workspace_root).resolve().parent / "shared" / "couchdb"


def missing_reason(scripts_dir: Path) -> Optional[str]:
    """Why the real CouchDB cannot run from `scripts_dir` (None when it can)."""
    for name in (NODE_SCRIPT, CLUSTER_SCRIPT, TARBALL):
        if not (Path(scripts_dir) / name).is_file():
            return (f"the real Apache CouchDB is not here: {Path(scripts_dir) / name} is missing "
                    f"(it comes with the shared folder beside the clone, ../shared/couchdb)")
    return None


def _ports_free(ports: Sequence[int]) -> bool:
    for port in ports:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                return False
    return True


def _free_base(offsets: Sequence[int]) -> int:
    """A port P in 20000..29000 with P + each offset free on 127.0.0.1 (below the ephemeral range,
    so outgoing connections do not take them)."""
    for _ in range(200):
        base = random.randint(20000, 29000)
        if _ports_free([base + offset for offset in offsets]):
            return base
    raise HarnessError("no free block of ports for CouchDB between 20000 and 30000")


def admin_hash(password: str) -> str:
    """The `[admins]` entry CouchDB itself would write for `password` (pbkdf2, sha256)."""
    salt = secrets.token_hex(16)
    key = hashlib.pbkdf2_hmac("sha256", password.encode(), salt.encode(), _HASH_ITERATIONS, 32)
    return f"-pbkdf2:sha256-{key.hex()},{salt},{_HASH_ITERATIONS}"


def beam_cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a process (e.g. a node's beam.smp) from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class _CouchCopy:
    """What a node and a cluster share: scripts, accounts, the admin's HTTP steps."""

    def __init__(self, scripts_dir: Path, work_dir: Path):
        reason = missing_reason(scripts_dir)
        if reason:
            raise HarnessError(reason)
        self.scripts_dir = Path(scripts_dir)
        self.dir = Path(work_dir)
        self.admin = ("admin", secrets.token_hex(12))
        self.member = (MEMBER, secrets.token_hex(12))
        self.epmd_port = 0
        self.ports: List[int] = []

    # -- scripts ----------------------------------------------------------------------------
    def _env(self) -> Dict[str, str]:
        env = dict(os.environ, ERL_EPMD_PORT=str(self.epmd_port))
        env.setdefault("COUCHDB_START_TIMEOUT", str(int(START_TIMEOUT * 2)))
        # Idle Erlang schedulers spin before they sleep: on a 2-core machine shared with the
        # tests that is CPU taken from them (about half of an idle node's CPU) for no answer.
        env.setdefault("ERL_AFLAGS", IDLE_SCHEDULERS_SLEEP)
        return env

    def _script(self, script: str, args: Sequence[str], *, env: Optional[Dict[str, str]] = None,
                secret: str = "") -> str:
        log = self.dir / "scripts.log"
        self.dir.mkdir(parents=True, exist_ok=True)
        done = subprocess.run([str(self.scripts_dir / script), *args], env=env or self._env(),
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              timeout=START_TIMEOUT * 4, stdin=subprocess.DEVNULL)
        out = done.stdout.replace(secret, "***") if secret else done.stdout
        with open(log, "a") as handle:
            handle.write(out)
        if done.returncode != 0:
            shown = [a.replace(secret, "***") if secret else a for a in args]
            raise HarnessError(f"{script} {' '.join(shown)} failed ({done.returncode}):\n"
                               f"{out[-3000:]}")
        return out

    def pids(self) -> List[int]:
        """The running beam.smp processes of this copy."""
        raise NotImplementedError

    def _log_cpu(self) -> None:
        """The CPU the running beam.smp processes used, into scripts.log (before they stop)."""
        with open(self.dir / "scripts.log", "a") as log:
            for pid in self.pids():
                log.write(f"beam.smp pid {pid}: {beam_cpu_seconds(pid):.2f} s CPU (user + system)\n")

    # -- HTTP as the admin --------------------------------------------------------------------
    @property
    def port(self) -> int:
        return self.ports[0]

    def plain_url(self, node: int = 0) -> str:
        return f"http://127.0.0.1:{self.ports[node]}"

    @property
    def url(self) -> str:
        """The first node's root with the admin's credentials (for the test's own requests)."""
        return self._with(self.admin, 0)

    def _with(self, account: Tuple[str, str], node: int) -> str:
        return f"http://{quote(account[0])}:{quote(account[1])}@127.0.0.1:{self.ports[node]}"

    def admin_request(self, method: str, path: str, body: object = None, *, node: int = 0,
                      ok: Sequence[int] = (200, 201, 202)) -> Tuple[int, dict]:
        """One request as the admin; (status, JSON body); HarnessError outside `ok`."""
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(self.plain_url(node) + path, data=data, method=method,
                                         headers={"Content-Type": "application/json",
                                                  "Authorization": _basic(self.admin)})
        try:
            with urllib.request.urlopen(request, timeout=60) as response:
                status, text = response.status, response.read()
        except urllib.error.HTTPError as err:
            status, text = err.code, err.read()
        answer = json.loads(text.decode() or "{}")  # a JSON value (an object for most requests)
        if status not in ok:
            raise HarnessError(f"CouchDB {method} {path} answered {status}: {answer}")
        return status, answer

    def _add_member_account(self) -> None:
        user, password = self.member
        # a new node creates _users itself a moment after /_up: our PUT may race with it, and
        # CouchDB then answers 500 "conflict" (seen on a busy machine); wait for the node's copy
        status, answer = self.admin_request("PUT", "/_users", ok=(201, 202, 412, 500))
        if status == 500:
            if answer.get("reason") != "conflict":
                raise HarnessError(f"CouchDB PUT /_users answered 500: {answer}")
            wait_until(lambda: self.admin_request("GET", "/_users", ok=(200, 404))[0] == 200,
                       START_TIMEOUT, what="the node's own _users database")
        self.admin_request("PUT", f"/_users/org.couchdb.user:{user}",
                           {"name": user, "password": password, "roles": [], "type": "user"},
                           ok=(201, 202, 409))

    def set_config(self, section: str, key: str, value: str, node: int = 0) -> str:
        """Change one server setting at run time (as the admin, on one node); returns the old value."""
        _, old = self.admin_request("PUT", f"/_node/_local/_config/{quote(section)}/{quote(key)}",
                                    value, node=node)  # type: ignore[arg-type]
        return str(old)

    def create_database(self, name: str) -> None:
        """The admin's step: the database, with the member account as its only member."""
        self.admin_request("PUT", "/" + quote(name, safe=""), ok=(201, 202, 412))
        self.admin_request("PUT", f"/{quote(name, safe='')}/_security",
                           {"admins": {"names": [], "roles": []},
                            "members": {"names": [self.member[0]], "roles": []}})

    def member_url(self, name: str, node: int = 0) -> str:
        """The URL the product uses: the member account on database `name` (not created here)."""
        return f"{self._with(self.member, node)}/{quote(name, safe='')}"

    def admin_database_url(self, name: str, node: int = 0) -> str:
        return f"{self._with(self.admin, node)}/{quote(name, safe='')}"

    def database_url(self, name: str, node: int = 0) -> str:
        """Database `name` created by the admin with the member set in `_security`; the member's URL."""
        self.create_database(name)
        return self.member_url(name, node)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def _basic(account: Tuple[str, str]) -> str:
    return "Basic " + b64encode(f"{account[0]}:{account[1]}".encode()).decode()


def _node_pid(node_dir: Path) -> Optional[int]:
    """The running beam.smp of the copy in `node_dir` (its couch.pid, checked against /proc)."""
    try:
        pid = int((node_dir / "couch.pid").read_text().strip())
        exe = os.readlink(f"/proc/{pid}/exe")
    except (OSError, ValueError):
        return None
    return pid if exe.startswith(str(node_dir.resolve()) + "/") and exe.endswith("/beam.smp") else None


class ApacheCouchDB(_CouchCopy):
    """One real Apache CouchDB 3 node unpacked into `work_dir`, on free ports."""

    def start(self) -> "ApacheCouchDB":
        if not self.ports:
            base = _free_base((0, 1000))
            self.ports = [base]
            self.epmd_port = _free_base((0,))
        env = dict(self._env(), COUCHDB_ADMIN_HASH=admin_hash(self.admin[1]))
        try:
            # the password is given as a hash (environment): never on a command line
            self._script(NODE_SCRIPT, ["start", str(self.dir), str(self.port), self.admin[0], "hashed"],
                         env=env)
            self._add_member_account()
        except BaseException:
            self.stop()  # a node that came up must not outlive a failed start
            raise
        return self

    @property
    def pid(self) -> Optional[int]:
        return _node_pid(self.dir)

    def pids(self) -> List[int]:
        return [pid for pid in [self.pid] if pid]

    def stop(self) -> None:
        if self.ports and (self.dir / "couch.pid").exists():
            self._log_cpu()
            self._script(NODE_SCRIPT, ["stop", str(self.dir)])

    def restart(self) -> "ApacheCouchDB":
        self.stop()
        return self.start()


class CouchDBCluster(_CouchCopy):
    """A real 3-node Apache CouchDB cluster (n = 3, q = 2) in `work_dir`/n1..n3, on free ports."""

    NODES = 3

    def start(self) -> "CouchDBCluster":
        """Starts the nodes that are not running (all of them the first time) and waits until the
        cluster is whole."""
        if not self.ports:
            base = _free_base((0, 1, 2, 1000, 1001, 1002))
            self.ports = [base + i for i in range(self.NODES)]
            self.epmd_port = _free_base((0,))
        try:
            # The cluster script takes the admin password as an argument (a throw-away test password).
            self._script(CLUSTER_SCRIPT, ["start", str(self.dir), str(self.port), *self.admin],
                         secret=self.admin[1])
            wait_until(self._whole, START_TIMEOUT, what="all three CouchDB nodes to answer /_up")
            self._add_member_account()
        except BaseException:
            self.stop()  # nodes that came up must not outlive a failed start
            raise
        return self

    def _whole(self) -> bool:
        for node in range(self.NODES):
            status, answer = self.admin_request("GET", "/_up", node=node, ok=(200, 404, 503))
            if status != 200:
                return False
        return True

    def node_pid(self, node: int) -> Optional[int]:
        return _node_pid(self.dir / f"n{node + 1}")

    def pids(self) -> List[int]:
        return [pid for pid in (self.node_pid(i) for i in range(self.NODES)) if pid]

    def kill_node(self, node: int) -> int:
        """SIGKILL one node's beam.smp (by its pid, no grace); returns the pid."""
        pid = self.node_pid(node)
        if pid is None:
            raise HarnessError(f"cluster node {node + 1} is not running")
        os.kill(pid, signal.SIGKILL)
        wait_until(lambda: not Path(f"/proc/{pid}").exists() or _zombie(pid), STOP_TIMEOUT,
                   what=f"CouchDB node {node + 1} (pid {pid}) to exit")
        return pid

    def stop(self) -> None:
        if self.ports and self.dir.is_dir():
            self._log_cpu()
            self._script(CLUSTER_SCRIPT, ["stop", str(self.dir)])


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True
