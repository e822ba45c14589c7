#!/usr/bin/env python3
"""A TCP-level MongoDB wire-protocol proxy that injects the answers a real mongod gives and
nx-27017 cannot produce (it has no accounts, and it ends a killed cursor silently).

    python mongo_fault_proxy.py --port 0 --upstream 127.0.0.1:27017 --mode read_only --ready FILE

Every message is forwarded unchanged, except OP_MSG (opcode 2013) commands that the mode refuses;
those are answered by the proxy itself, byte-compatible with mongod's own reply (an OP_MSG whose
body is {ok: 0, errmsg, code, codeName}, responseTo = the request's id):
- read_only: an account with the `read` role: insert/update/delete/findAndModify/createIndexes/
  create/drop... get 13 Unauthorized ("not authorized on <db> to execute command ...").
- no_index: an account with `readWrite` but no createIndex: createIndexes gets 13 Unauthorized.
- lose_cursors: every getMore gets 43 CursorNotFound ("cursor id N not found"), as mongod answers
  after its 10-minute idle timeout or a killCursors.
Refused commands are appended to --log (one command name a line). The chosen port is written to
--ready once listening.
"""
import argparse
import os
import socket
import struct
import threading

import bson

OP_MSG = 2013
WRITE_COMMANDS = {"insert", "update", "delete", "findandmodify", "createindexes", "create", "drop",
                  "dropindexes", "dropdatabase", "renamecollection"}


def refusal(mode: str, command: str, body: dict):
    name = command.lower()
    db = body.get("$db", "?")
    if mode == "read_only" and name in WRITE_COMMANDS or mode == "no_index" and name == "createindexes":
        return {"ok": 0.0, "errmsg": f"not authorized on {db} to execute command "
                                     f"{{ {command}: \"{body.get(command)}\" }}",
                "code": 13, "codeName": "Unauthorized"}
    if mode == "lose_cursors" and name == "getmore":
        return {"ok": 0.0, "errmsg": f"cursor id {body.get(command)} not found", "code": 43,
                "codeName": "CursorNotFound"}
    return None


def read_exact(sock: socket.socket, size: int) -> bytes:
    data = b""
    while len(data) < size:
        chunk = sock.recv(size - len(data))
        if not chunk:
            raise ConnectionError("closed")
        data += chunk
    return data


def command_of(message: bytes):
    """(command name, body) of an OP_MSG's section 0, or None."""
    opcode = struct.unpack_from("<i", message, 12)[0]
    if opcode != OP_MSG:
        return None
    pos = 20  # header (16) + flagBits (4)
    while pos < len(message):
        kind = message[pos]
        pos += 1
        size = struct.unpack_from("<i", message, pos)[0]
        if kind == 0:
            body = bson.decode(message[pos:pos + size])
            return next(iter(body)), body
        pos += size
    return None


def reply(request_id: int, body: dict) -> bytes:
    payload = struct.pack("<I", 0) + b"\x00" + bson.encode(body)
    return struct.pack("<iiii", 16 + len(payload), request_id + 1_000_000, request_id, OP_MSG) + payload


def pump(source: socket.socket, sink: socket.socket) -> None:
    try:
        while True:
            data = source.recv(65536)
            if not data:
                break
            sink.sendall(data)
    except OSError:
        pass
    finally:
        for s in (source, sink):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass


def serve(client: socket.socket, upstream, mode: str, log_path: str, lock: threading.Lock) -> None:
    server = socket.create_connection(upstream)
    threading.Thread(target=pump, args=(server, client), daemon=True).start()
    try:
        while True:
            header = read_exact(client, 16)
            length, request_id = struct.unpack_from("<ii", header)
            message = header + read_exact(client, length - 16)
            parsed = command_of(message)
            answer = refusal(mode, *parsed) if parsed else None
            if answer is None:
                server.sendall(message)
                continue
            if log_path:
                with lock, open(log_path, "a") as log:
                    log.write(parsed[0] + "\n")
            with lock:
                client.sendall(reply(request_id, answer))
    except (ConnectionError, OSError):
        pass
    finally:
        for s in (client, server):
            try:
                s.close()
            except OSError:
                pass


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--upstream", required=True, help="host:port of the real server")
    parser.add_argument("--mode", choices=["read_only", "no_index", "lose_cursors", "pass"], required=True)
    parser.add_argument("--ready", required=True, help="file to write the listening port to")
    parser.add_argument("--log", default="", help="file to append refused command names to")
    args = parser.parse_args()
    host, port = args.upstream.rsplit(":", 1)
    listener = socket.socket()
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    listener.bind(("127.0.0.1", args.port))
    listener.listen(64)
    with open(args.ready + ".tmp", "w") as ready:
        ready.write(str(listener.getsockname()[1]))
    os.replace(args.ready + ".tmp", args.ready)
    lock = threading.Lock()
    while True:
        client, _ = listener.accept()
        threading.Thread(target=serve, args=(client, (host, int(port)), args.mode, args.log, lock),
                         daemon=True).start()


if __name__ == "__main__":
    main()
