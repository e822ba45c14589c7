#!/usr/bin/env python3
"""Central CPU per message on a real Apache CouchDB: what one robot's standard load costs the
server, by the way its documents travel.

    scripts/in_env.sh python bench/ros_mongo/central_cpu.py              # about 3 min
    scripts/in_env.sh python bench/ros_mongo/central_cpu.py --seconds 5  # a smoke run

A real Apache CouchDB 3.5 node (../shared/couchdb, started in a temporary folder on free ports, a
database member account writing) takes `--seconds` (20) of the standard load's odometry (1 kHz
nav_msgs/Odometry) and camera images (30 Hz 640x480 rgb8), built as the recorder builds them
(ros_mongo.recording.record_builder, ~decode full) and written as ros_mongo's CouchDB backend writes them:

- odometry, a document per message (batches of 500, `_bulk_docs`), and as chunks
  (ros_mongo.storage.chunks: one document per second or per 1000 messages, the bytes as one attachment);
- both again with the server's `[couchdb] attachment_stream_buffer_size` at 1 MB (default 4 KB: the
  size of the pieces an attachment is written in);
- images, three ways the server takes a binary payload: base64 inside `_bulk_docs` JSON (inline
  attachments, batches of about 24 MB), the document then the bytes as a binary attachment
  (`_bulk_docs` + `PUT /db/doc/raw?rev=`), and one `multipart/related` `PUT /db/doc?new_edits=false`
  per image (the JSON and the raw bytes in one request, as CouchDB's replicator writes); plus the
  backend's own path (`CouchStore.insert_records`).

The figure is the server's CPU (beam.smp, user + system from /proc) from the first request until
it is idle again, minus its idle rate, per message and per MB of payload. Targets: <= 0.1 ms per
odometry message, <= 10 ms per MB of image. Figures go to artifacts/bench/central_cpu.json.
"""
import argparse
import json
import os
import sys
import tempfile
import time
import uuid
from pathlib import Path

import genpy
import requests

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))

from bench_publisher import samples  # noqa: E402 - after the path set-up

from ros_harness.apache_couchdb import ApacheCouchDB, beam_cpu_seconds, shared_couchdb_dir  # noqa: E402
from ros_mongo import open_store  # noqa: E402
from ros_mongo.messages.decoding import DecodePolicy  # noqa: E402
from ros_mongo.recording.record_builder import RecordBuilder  # noqa: E402
from ros_mongo.records import TopicInfo  # noqa: E402
from ros_mongo.storage.chunks import CHUNK_SPAN, ChunkRecord  # noqa: E402
from ros_mongo.storage.couch import message_rev  # noqa: E402
from ros_mongo.storage.documents import message_doc  # noqa: E402

T0 = 1_800_000_000


def say(text=""):
    print(text, flush=True)


def serialized(msg) -> bytes:
    from io import BytesIO
    buffer = BytesIO()
    msg.serialize(buffer)
    return buffer.getvalue()


def build_records(topic, msg, rate, seconds):
    """Records of `seconds` of `topic` at `rate`, as the recorder builds them (its builder, ~decode full)."""
    info = TopicInfo.of_class(topic, type(msg), robot_id="robot1")
    key = (topic, info.msg_type, info.md5sum, "")
    builder = RecordBuilder({key: info}, decode=DecodePolicy(), session_id="bench", robot_id="robot1")
    records = []
    for index in range(int(rate * seconds)):
        msg.header.seq = index
        stamp = genpy.Time.from_sec(T0 + index / rate)
        msg.header.stamp = stamp
        records.append(builder.record(key, serialized(msg), stamp.secs, stamp.nsecs))
    return info, records


def chunked(records, max_messages=1000):
    chunks, current = [], []
    for record in records:
        if current and (len(current) >= max_messages
                        or record.receive_time - current[0].receive_time >= CHUNK_SPAN):
            chunks.append(ChunkRecord(current))
            current = []
        current.append(record)
    return chunks + ([ChunkRecord(current)] if current else [])


class CpuMeter:
    """The server's CPU for one stage: from before its first request until it is idle again,
    minus its idle rate."""

    def __init__(self, pid):
        self.pid = pid
        self.idle_rate = self._rate(2.0)

    def _rate(self, seconds):
        before = beam_cpu_seconds(self.pid)
        time.sleep(seconds)
        return (beam_cpu_seconds(self.pid) - before) / seconds

    def measure(self, work):
        began, cpu0 = time.monotonic(), beam_cpu_seconds(self.pid)
        work()
        wrote = time.monotonic() - began
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and self._rate(0.5) > max(0.02, 2 * self.idle_rate):
            pass
        took = time.monotonic() - began
        return {"cpu_s": beam_cpu_seconds(self.pid) - cpu0 - self.idle_rate * took, "write_s": wrote}


def write_product(url, info, records):
    """As the recorder writes: CouchStore.insert_records in batches of 500 entries."""
    def work():
        with open_store(url) as store:
            store.put_topic(info)
            for start in range(0, len(records), 500):
                store.insert_records(records[start:start + 500])
    return work


def _doc_json(record, rev=True):
    doc = message_doc(record)
    if rev:
        doc["_rev"] = message_rev(record.id)
    return doc


def write_inline_base64(url, records, session):
    """Images as base64 inline attachments in `_bulk_docs` (new_edits false), ~24 MB per request."""
    import base64

    def work():
        batch, size = [], 0
        for record in records + [None]:
            if record is None or (batch and size + len(record.raw) * 4 // 3 > 24 * 2 ** 20):
                answer = session.post(f"{url}/_bulk_docs", json={"new_edits": False, "docs": batch},
                                      timeout=300)
                answer.raise_for_status()
                batch, size = [], 0
            if record is None:
                break
            doc = _doc_json(record)
            doc["_attachments"] = {"raw": {"content_type": "application/octet-stream",
                                           "data": base64.b64encode(record.raw).decode("ascii")}}
            batch.append(doc)
            size += len(record.raw) * 4 // 3
    return work


def write_binary_put(url, records, session):
    """The documents in `_bulk_docs` (batches of 100), then each image as a binary attachment PUT."""
    def work():
        for start in range(0, len(records), 100):
            part = records[start:start + 100]
            answer = session.post(f"{url}/_bulk_docs", json={"docs": [_doc_json(r, rev=False) for r in part]},
                                  timeout=300)
            answer.raise_for_status()
            revs = {item["id"]: item["rev"] for item in answer.json()}
            for record in part:
                put = session.put(f"{url}/{record.id}/raw", params={"rev": revs[record.id]}, data=record.raw,
                                  headers={"Content-Type": "application/octet-stream"}, timeout=300)
                put.raise_for_status()
    return work


def multipart_body(doc: dict, raw: bytes):
    """A `multipart/related` document body: its JSON (the attachment as a stub that follows), then
    the attachment's bytes."""
    boundary = uuid.uuid4().hex
    doc = dict(doc, _attachments={"raw": {"content_type": "application/octet-stream", "length": len(raw),
                                          "follows": True}})
    head = (f"--{boundary}\r\nContent-Type: application/json\r\n\r\n").encode() + json.dumps(doc).encode() + \
        (f"\r\n--{boundary}\r\nContent-Type: application/octet-stream\r\n\r\n").encode()
    return [head, raw, f"\r\n--{boundary}--".encode()], f'multipart/related; boundary="{boundary}"'


def write_multipart(url, records, session):
    """One `multipart/related` PUT per image (new_edits false, the revision the backend gives)."""
    def work():
        for record in records:
            parts, content_type = multipart_body(_doc_json(record), record.raw)
            put = session.put(f"{url}/{record.id}", params={"new_edits": "false"}, data=b"".join(parts),
                              headers={"Content-Type": content_type}, timeout=300)
            put.raise_for_status()
    return work


def stored(url, session, n):
    info = session.get(url, timeout=60).json()
    return info.get("doc_count", 0) - n


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="seconds of the standard load (20)")
    parser.add_argument("--output", type=Path, default=ROOT / "artifacts" / "bench")
    args = parser.parse_args(argv)
    scripts = shared_couchdb_dir(ROOT)
    msgs = samples()
    say(f"building {args.seconds:.0f} s of odometry (1 kHz) and images (30 Hz) as the recorder does ...")
    odom_info, odom = build_records("/odom", msgs["/odom"], 1000.0, args.seconds)
    image_info, images = build_records("/camera/rgb/image_raw", msgs["/camera/rgb/image_raw"], 30.0,
                                       args.seconds)
    image_mb = sum(len(r.raw) for r in images) / 1e6
    results = {"seconds": args.seconds, "odometry_messages": len(odom), "images": len(images),
               "image_mb": image_mb, "load_before": os.getloadavg()}
    with tempfile.TemporaryDirectory(prefix="central_cpu_") as work_dir, \
            ApacheCouchDB(scripts, Path(work_dir) / "couchdb") as couch:
        meter = CpuMeter(couch.pid)
        session = requests.Session()
        results["idle_cpu_per_s"] = meter.idle_rate
        stages = [
            ("odometry, a document per message", odom, lambda url: write_product(url, odom_info, odom)),
            ("odometry, chunks", odom, lambda url: write_product(url, odom_info, chunked(odom))),
            ("images, backend (CouchStore.insert_records)", images,
             lambda url: write_product(url, image_info, images)),
            ("images, base64 inline in _bulk_docs", images,
             lambda url: write_inline_base64(url, images, session)),
            ("images, document + binary attachment PUT", images,
             lambda url: write_binary_put(url, images, session)),
            ("images, multipart/related PUT", images, lambda url: write_multipart(url, images, session)),
        ]
        tuned = ("attachment_stream_buffer_size 1 MB", "couchdb", "attachment_stream_buffer_size", "1048576")
        stages += [("odometry, chunks; " + tuned[0], odom,
                    lambda url: write_product(url, odom_info, chunked(odom))),
                   ("images, backend; " + tuned[0], images,
                    lambda url: write_product(url, image_info, images))]
        results["stages"] = {}
        for index, (name, records, make) in enumerate(stages):
            if name.endswith(tuned[0]):
                couch.set_config(*tuned[1:])
            database = f"central_cpu_{index}"
            couch.create_database(database)
            url = couch.member_url(database)
            session.auth = requests.utils.get_auth_from_url(url)
            plain = couch.plain_url() + "/" + database
            figures = meter.measure(make(url if "backend" in name or "odometry" in name else plain))
            figures["stored"] = stored(plain, session, 0)
            megabytes = sum(len(r.raw) for r in records) / 1e6
            figures["ms_per_message"] = figures["cpu_s"] * 1e3 / len(records)
            figures["ms_per_mb"] = figures["cpu_s"] * 1e3 / megabytes
            results["stages"][name] = figures
            say(f"{name:48s} server CPU {figures['cpu_s']:6.2f} s: {figures['ms_per_message']:7.3f} ms per "
                f"message, {figures['ms_per_mb']:7.2f} ms per MB (written in {figures['write_s']:.1f} s, "
                f"{figures['stored']} documents)")
    results["load_after"] = os.getloadavg()
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / "central_cpu.json").write_text(json.dumps(results, indent=1))
    say(f"\nload average before {results['load_before'][0]:.1f}, after {results['load_after'][0]:.1f} "
        f"({os.cpu_count()} CPUs); figures in {args.output / 'central_cpu.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
