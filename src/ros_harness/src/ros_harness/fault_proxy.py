"""A fault-injecting HTTP proxy in front of a real CouchDB-compatible server (pouchdb-server).

pouchdb-server has no accounts, no document size limit and no cluster, so it never gives the
answers a real Apache CouchDB 3 gives a robot. This proxy is a real process on its own port that
forwards every request to the real server, and on demand answers instead exactly as Apache CouchDB
3.5 does (status and JSON bodies measured on a real Apache CouchDB 3.5.0):

- `auth`: "wrong_password" | "no_credentials" | "not_admin": every request answers 401 with
  CouchDB's reason ("Name or password is incorrect." / "You are not authorized to access this
  db." / "You are not a server admin."); with `auth_scope: "writes"` only writes do (a database
  that anyone may read, a writer whose password was rotated).
- `require_auth` ("user:password"): requests without exactly these Basic credentials answer 401
  "Name or password is incorrect." (a rotated password; set it back: the operator fixed it).
- `member`: a database member account: `PUT /db` -> 401 not a server admin, `POST /db/_index` ->
  500 `error_saving_ddoc` forbidden, `PUT/DELETE /db/_design/...` and `/db/_security` -> 403.
- `index_conflict`: `POST /db/_index` is forwarded (the index is created) and answered with 500
  `error_saving_ddoc` conflict, as when several robots create it at once.
- `max_document_size` (bytes): a `_bulk_docs` request holding a larger document -> 413
  `document_too_large` naming that document's id, for the whole request (nothing stored).
- `timeout`: "writes" | "all": 500 `{"error":"timeout",...}` without forwarding.
- `accepted_202`: writes are forwarded and their 201 answered as 202 (no write quorum).
- `truncate_find` (count): that many `_find` answers are sent chunked and cut off mid-body.
- `latency` (seconds): added before every forwarded request.
- `bulk_answer` (text): `_bulk_docs` answered 201 with this body, nothing forwarded (an answer of
  an unexpected shape).
- Start option `--prefix /couchdb`: the proxy serves the server under that path prefix (as a
  reverse proxy does); other paths answer 404.
- Start options `--tls-cert FILE --tls-key FILE` (HTTPS with that server certificate, e.g. from a
  private CA) and `--tls-client-ca FILE` (also require a client certificate signed by that CA).

Control (while clients run; over HTTPS when TLS is on, so use `FaultProxy.set` only without TLS):
`PUT /_fault_proxy` with a JSON object replaces the faults (`{}` clears
them), `GET /_fault_proxy` answers `{"faults": {...}, "answered": {"<fault>": count}}`.

    python3 -m ros_harness.fault_proxy --port 6001 --upstream http://127.0.0.1:5984 [--prefix /couchdb]

`FaultProxy` starts it as a managed child process on a free port (tests, benchmarks).
"""
import argparse
import base64
import http.client
import json
import ssl
import sys
import threading
import time
import urllib.request
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Dict, Optional
from urllib.parse import urlsplit

from ros_harness.processes import ManagedProcess, free_port, port_open, wait_until

__all__ = ["FaultProxy", "AUTH_REASONS", "main"]

CONTROL = "/_fault_proxy"
AUTH_REASONS = {
    "wrong_password": "Name or password is incorrect.",
    "no_credentials": "You are not authorized to access this db.",
    "not_admin": "You are not a server admin.",
}
_DDOC_FORBIDDEN = {"error": "error_saving_ddoc",
                   "reason": "Unknown error while saving the design document: forbidden", "ref": 3269388020}
_DDOC_CONFLICT = {"error": "error_saving_ddoc",
                  "reason": "Unknown error while saving the design document: conflict", "ref": 1430546735}
_TIMEOUT = {"error": "timeout",
            "reason": "The request could not be processed in a reasonable amount of time."}
_FORBIDDEN = {"error": "forbidden", "reason": "You are not a db or server admin."}
_WRITES = ("PUT", "POST", "DELETE")


class _State:
    def __init__(self):
        self.lock = threading.Lock()
        self.faults: Dict[str, object] = {}
        self.answered: Dict[str, int] = {}

    def count(self, fault: str) -> None:
        with self.lock:
            self.answered[fault] = self.answered.get(fault, 0) + 1

    def take_truncation(self) -> bool:
        with self.lock:
            left = int(self.faults.get("truncate_find") or 0)
            if left <= 0:
                return False
            self.faults["truncate_find"] = left - 1
            return True


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    server_version = "CouchDB/3.5.0 (Erlang OTP/26)"
    state: _State
    upstream: str
    prefix: str

    def log_message(self, format, *args):  # noqa: A002 - BaseHTTPRequestHandler's signature
        pass

    def do_GET(self):
        self._handle()

    def do_PUT(self):
        self._handle()

    def do_POST(self):
        self._handle()

    def do_DELETE(self):
        self._handle()

    def do_HEAD(self):
        self._handle()

    def _body(self) -> bytes:
        if "chunked" in (self.headers.get("Transfer-Encoding") or "").lower():
            return self._chunked_body()  # what Node's HTTP client sends for streamed bodies
        length = int(self.headers.get("Content-Length") or 0)
        return self.rfile.read(length) if length else b""

    def _chunked_body(self) -> bytes:
        parts = []
        while True:
            size = int(self.rfile.readline().split(b";")[0].strip() or b"0", 16)
            if size == 0:
                while self.rfile.readline() not in (b"\r\n", b"\n", b""):
                    pass  # trailer fields
                return b"".join(parts)
            parts.append(self.rfile.read(size))
            self.rfile.readline()  # the CRLF after each chunk

    def _answer(self, status: int, body, *, fault: Optional[str] = None) -> None:
        if fault:
            self.state.count(fault)
        data = body if isinstance(body, bytes) else json.dumps(body).encode()
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)

    def _handle(self) -> None:
        body = self._body()
        path = self.path
        if path.split("?")[0] == CONTROL:
            return self._control(body)
        if self.prefix:
            if not (path == self.prefix or path.startswith(self.prefix + "/")):
                return self._answer(404, {"error": "not_found", "reason": "outside the proxy prefix"})
            path = path[len(self.prefix):] or "/"
        with self.state.lock:
            faults = dict(self.state.faults)
        route = path.split("?")[0]
        parts = [p for p in route.split("/") if p]
        method = self.command
        if faults.get("require_auth") and self.headers.get("Authorization") != "Basic " + base64.b64encode(
                str(faults["require_auth"]).encode()).decode():
            return self._answer(401, {"error": "unauthorized", "reason": AUTH_REASONS["wrong_password"]},
                                fault="auth")
        if faults.get("auth") and (faults.get("auth_scope") != "writes"
                                   or (method in _WRITES and route.split("/")[-1] != "_find")):
            return self._answer(401, {"error": "unauthorized", "reason": AUTH_REASONS[faults["auth"]]},
                                fault="auth")
        if faults.get("timeout") == "all" or (faults.get("timeout") == "writes" and method in _WRITES
                                              and route.split("/")[-1] != "_find"):
            return self._answer(500, _TIMEOUT, fault="timeout")
        if faults.get("member"):
            if len(parts) == 1 and method in ("PUT", "DELETE"):
                return self._answer(401, {"error": "unauthorized", "reason": AUTH_REASONS["not_admin"]},
                                    fault="member")
            if len(parts) >= 2 and parts[1] == "_index" and method == "POST":
                return self._answer(500, _DDOC_FORBIDDEN, fault="member")
            if len(parts) >= 2 and parts[1] in ("_design", "_security") and method in ("PUT", "DELETE"):
                return self._answer(403, _FORBIDDEN, fault="member")
        if len(parts) == 2 and parts[1] == "_bulk_docs" and method == "POST":
            if faults.get("bulk_answer") is not None:
                return self._answer(201, str(faults["bulk_answer"]).encode(), fault="bulk_answer")
            limit = faults.get("max_document_size")
            if limit:
                too_large = _too_large(body, int(limit))
                if too_large is not None:
                    return self._answer(413, {"error": "document_too_large", "reason": too_large},
                                        fault="max_document_size")
        if faults.get("latency"):
            time.sleep(float(faults["latency"]))
        status, headers, data = self._forward(method, path, body)
        if len(parts) == 2 and parts[1] == "_index" and method == "POST" and faults.get("index_conflict"):
            return self._answer(500, _DDOC_CONFLICT, fault="index_conflict")
        if faults.get("accepted_202") and method in _WRITES and status == 201:
            self.state.count("accepted_202")
            status = 202
        if len(parts) == 2 and parts[1] == "_find" and self.state.take_truncation():
            self.state.count("truncate_find")
            return self._truncated(status, data)
        self.send_response(status)
        for key, value in headers:
            if key.lower() not in ("content-length", "transfer-encoding", "connection", "server", "date"):
                self.send_header(key, value)
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        if method != "HEAD":
            self.wfile.write(data)

    def _forward(self, method: str, path: str, body: bytes):
        target = urlsplit(self.upstream)
        connection = http.client.HTTPConnection(target.hostname, target.port, timeout=120)
        headers = {k: v for k, v in self.headers.items()
                   if k.lower() not in ("host", "connection", "authorization", "content-length",
                                        "transfer-encoding")}  # the body goes on whole
        headers["Content-Length"] = str(len(body))
        try:
            connection.request(method, path, body=body, headers=headers)
            response = connection.getresponse()
            data = response.read()
            return response.status, response.getheaders(), data
        except OSError as err:
            return 502, [], json.dumps({"error": "bad_gateway", "reason": str(err)}).encode()
        finally:
            connection.close()

    def _truncated(self, status: int, data: bytes) -> None:
        """A chunked answer cut off in the middle: half the body, then the connection closes."""
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Transfer-Encoding", "chunked")
        self.end_headers()
        half = data[:max(1, len(data) // 2)]
        self.wfile.write(b"%x\r\n%s\r\n" % (len(half), half))
        self.wfile.flush()
        self.close_connection = True

    def _control(self, body: bytes) -> None:
        if self.command == "PUT":
            try:
                faults = json.loads(body.decode() or "{}")
                if not isinstance(faults, dict):
                    raise ValueError("not an object")
                if faults.get("auth") and faults["auth"] not in AUTH_REASONS:
                    raise ValueError(f"auth must be one of {sorted(AUTH_REASONS)}")
            except ValueError as err:
                return self._answer(400, {"error": "bad_request", "reason": str(err)})
            with self.state.lock:
                self.state.faults = faults
        with self.state.lock:
            answer = {"faults": dict(self.state.faults), "answered": dict(self.state.answered)}
        self._answer(200, answer)


def _too_large(body: bytes, limit: int) -> Optional[str]:
    """The id of the first document of a `_bulk_docs` body whose JSON is longer than `limit`."""
    try:
        docs = json.loads(body.decode("utf-8")).get("docs", [])
    except (ValueError, AttributeError):
        return None
    for doc in docs:
        if len(json.dumps(doc, separators=(",", ":"))) > limit:
            return str(doc.get("_id", ""))
    return None


def serve(port: int, upstream: str, prefix: str = "", host: str = "127.0.0.1", *,
          tls_cert: Optional[str] = None, tls_key: Optional[str] = None,
          tls_client_ca: Optional[str] = None) -> ThreadingHTTPServer:
    """A started proxy server (serve_forever runs on a daemon thread)."""
    handler = type("FaultProxyHandler", (_Handler,), {"state": _State(), "upstream": upstream,
                                                      "prefix": prefix.rstrip("/")})
    server = ThreadingHTTPServer((host, port), handler)
    server.daemon_threads = True
    if tls_cert:
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        context.load_cert_chain(tls_cert, tls_key)
        if tls_client_ca:
            context.verify_mode = ssl.CERT_REQUIRED
            context.load_verify_locations(tls_client_ca)
        server.socket = context.wrap_socket(server.socket, server_side=True)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


class FaultProxy:
    """The proxy as a real child process on a free port, in front of `upstream` (http://host:port)."""

    def __init__(self, upstream: str, log_dir: Path, *, prefix: str = "", port: Optional[int] = None,
                 tls: Optional[Dict[str, str]] = None):
        self.upstream, self.prefix = upstream.rstrip("/"), prefix.rstrip("/")
        self.port = port or free_port()
        self.tls = dict(tls or {})  # cert, key, client_ca (files)
        scheme = "https" if self.tls else "http"
        self.url = f"{scheme}://127.0.0.1:{self.port}{self.prefix}"
        self.control_url = f"http://127.0.0.1:{self.port}{CONTROL}"
        self.log_dir = Path(log_dir)
        self.process = None

    def start(self, timeout: float = 60.0) -> "FaultProxy":
        argv = [sys.executable, "-m", "ros_harness.fault_proxy", "--port", str(self.port), "--upstream",
                self.upstream]
        if self.prefix:
            argv += ["--prefix", self.prefix]
        for key in ("cert", "key", "client_ca"):
            if self.tls.get(key):
                argv += [f"--tls-{key.replace('_', '-')}", str(self.tls[key])]
        self.process = ManagedProcess(argv, name=f"fault proxy :{self.port}",
                                       log_path=self.log_dir / f"fault_proxy_{self.port}.log").start()
        ready = (lambda: port_open(self.port)) if self.tls else (lambda: self.state() is not None)
        wait_until(ready, timeout, what=f"fault proxy on port {self.port}", check=self.process.check_alive)
        return self

    def stop(self) -> None:
        if self.process is not None:
            self.process.stop(timeout=10)

    def database_url(self, name: str) -> str:
        return f"{self.url}/{name}"

    def state(self) -> dict:
        with urllib.request.urlopen(self.control_url, timeout=5) as response:
            return json.loads(response.read().decode())

    def set(self, **faults) -> dict:
        """Replace the active faults (none given: clear them); returns the proxy's state."""
        request = urllib.request.Request(self.control_url, data=json.dumps(faults).encode(), method="PUT",
                                         headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(request, timeout=5) as response:
            return json.loads(response.read().decode())

    def clear(self) -> dict:
        return self.set()

    def answered(self, fault: str) -> int:
        """How many requests were answered with `fault` so far."""
        return int(self.state()["answered"].get(fault, 0))

    def __enter__(self) -> "FaultProxy":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python3 -m ros_harness.fault_proxy",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--upstream", required=True, help="the real server, http://host:port")
    parser.add_argument("--prefix", default="", help="serve under this path prefix (/couchdb)")
    parser.add_argument("--tls-cert", help="serve HTTPS with this certificate (PEM)")
    parser.add_argument("--tls-key", help="its private key (PEM)")
    parser.add_argument("--tls-client-ca", help="require client certificates signed by this CA")
    args = parser.parse_args(argv)
    server = serve(args.port, args.upstream, args.prefix, tls_cert=args.tls_cert, tls_key=args.tls_key,
                   tls_client_ca=args.tls_client_ca)
    print(f"fault proxy on 127.0.0.1:{args.port}{args.prefix} -> {args.upstream}", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        server.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
