#!/usr/bin/env python3
"""An HTTP proxy in front of pouchdb-server whose `_changes` feed is ordered as Apache CouchDB's
sharded feed can be (q = 2), deterministically, for tests of the changes follower.

    python sharded_feed_proxy.py --upstream http://127.0.0.1:5984 --ready FILE
    # then http://127.0.0.1:PORT/<order>/<db>/...  with <order>: fair, slow0 or slow1

Apache CouchDB splits a database into shards by document id and answers `_changes` by streaming
every shard's changes at once, passing rows on in the order they reach it, anew on each request:
when one shard's worker answers late (a busy node), a page fills with the other shard's changes
first. pouchdb-server has one ordered feed; this proxy serves it as two shards (shard =
crc32(id) % 2) whose rows are passed on, in each answer, in pouchdb-server's order (`fair`) or
with every row of shard K after the other shard's (`slowK`: shard K's worker answered last).
Sequences are vectors, "<a + b>-<a>.<b>": the last pouchdb-server sequence passed on from each
shard; every row carries the vector after it, as Apache CouchDB's rows do; any order resumes from
any of them. `limit` and `include_docs` are honoured; every other GET (documents, attachments) is
forwarded unchanged. Only GET: the tests write to pouchdb-server directly. The chosen port is
written to --ready once listening.
"""
import argparse
import json
import os
import zlib
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qs, urlsplit

import requests

ORDERS = ("fair", "slow0", "slow1")


def shard_of(doc_id: str) -> int:
    return zlib.crc32(doc_id.encode()) % 2


def parse_since(since: str):
    """(a, b): the pouchdb-server sequence each shard was read up to."""
    if since in ("", "0"):
        return [0, 0]
    first, second = since.split("-", 1)[1].split(".")
    return [int(first), int(second)]


def pack(vector) -> str:
    return f"{vector[0] + vector[1]}-{vector[0]}.{vector[1]}"


def sharded_feed(rows, since: str, limit: int, order: str) -> dict:
    """The changes after `since` of pouchdb-server's feed `rows` (in its order), as two shards'
    streams reaching a coordinator in `order` (fair, slow0, slow1)."""
    vector = parse_since(since)
    after = [row for row in rows if row["seq"] > vector[shard_of(row["id"])]]
    if order.startswith("slow"):
        late = int(order[4:])
        after.sort(key=lambda row: shard_of(row["id"]) == late)   # stable: each shard in order
    results = []
    for row in after[:limit]:
        vector[shard_of(row["id"])] = row["seq"]
        results.append(dict(row, seq=pack(vector)))
    return {"results": results, "last_seq": pack(vector), "pending": len(after) - len(results)}


class Handler(BaseHTTPRequestHandler):
    upstream = ""

    def do_GET(self):  # noqa: N802 (http.server's name)
        parts = urlsplit(self.path)
        order, _, path = parts.path.lstrip("/").partition("/")
        if order not in ORDERS:
            self._answer(404, "application/json", b'{"error":"not_found","reason":"no such order"}')
            return
        if path.endswith("/_changes"):
            query = {key: values[-1] for key, values in parse_qs(parts.query).items()}
            params = {"since": "0", "include_docs": query.get("include_docs", "false")}
            feed = requests.get(f"{self.upstream}/{path}", params=params, timeout=60).json()
            limit = int(query.get("limit", len(feed["results"])))
            answer = sharded_feed(feed["results"], query.get("since", "0"), limit, order)
            self._answer(200, "application/json", json.dumps(answer).encode())
            return
        forwarded = f"{self.upstream}/{path}" + (f"?{parts.query}" if parts.query else "")
        answer = requests.get(forwarded, timeout=60, headers={"Accept": self.headers.get("Accept", "*/*")})
        self._answer(answer.status_code, answer.headers.get("Content-Type", "application/json"),
                     answer.content)

    def _answer(self, status: int, content_type: str, body: bytes) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args) -> None:  # quiet
        pass


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--upstream", required=True, help="the pouchdb-server root URL")
    parser.add_argument("--ready", required=True, help="file to write the listening port to")
    args = parser.parse_args()
    Handler.upstream = args.upstream.rstrip("/")
    server = ThreadingHTTPServer(("127.0.0.1", args.port), Handler)
    with open(args.ready + ".tmp", "w") as ready:
        ready.write(str(server.server_address[1]))
    os.replace(args.ready + ".tmp", args.ready)
    server.serve_forever()


if __name__ == "__main__":
    main()
