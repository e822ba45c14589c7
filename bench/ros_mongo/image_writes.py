#!/usr/bin/env python3
"""Robot-side CPU per image written to CouchDB, by the way the backend sends it: one image per
`insert_records` call (as a released `upload: when` part goes through a 2 MB/s cap), 640x480 rgb8
images (921,641 bytes serialized), in this process, CPU from getrusage (user + system).

Ways: `multipart` (one `multipart/related` PUT per image, no lookup: the recorder's writes),
`multipart+lookup` (the same after an `_all_docs` lookup: `insert_records`' default), `base64+lookup`
(base64 attachments inside `_bulk_docs` after a lookup: the backend's writes before 2026-11-29, and
its fallback while multipart writes are off). Each way writes `--images` new images, then the same
ones again (a retry). Servers: pouchdb-server and, where ../shared/couchdb is, a real Apache
CouchDB 3.5 node (a member account).

    scripts/in_env.sh python bench/ros_mongo/image_writes.py               # about 1 min
"""
import argparse
import io
import json
import resource
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))

from bench_publisher import samples  # noqa: E402 - after the path set-up

from ros_harness import ApacheCouchDB, PouchDBServer  # noqa: E402
from ros_harness.apache_couchdb import missing_reason, shared_couchdb_dir  # noqa: E402
from ros_mongo import open_store  # noqa: E402
from ros_mongo.records import TopicInfo, make_record, split_time  # noqa: E402

CAMERA = "/camera/rgb/image_raw"
WAYS = {"multipart": (False, False), "multipart+lookup": (False, True), "base64+lookup": (True, True)}


def cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def run_way(url: str, way: str, images: int, start: float) -> dict:
    base64, look_up = WAYS[way]
    image = samples()[CAMERA]
    buffer = io.BytesIO()
    image.serialize(buffer)
    records = [make_record(CAMERA, type(image), buffer.getvalue(), receive=split_time(start + i / 30),
                           robot_id="robot1", decode="index") for i in range(images)]
    with open_store(url) as store:
        store.connect()
        store.put_topic(TopicInfo.of_class(CAMERA, type(image), robot_id="robot1"))
        if base64:
            store._multipart_off_until = float("inf")
        weight = sum(w for _, _, w in store.prepare_records(records[:1]).items)
        figures = {"bytes_per_image": weight}
        for label in ("new", "again"):
            before = cpu()
            for record in records:
                store.insert_records([record], look_up=look_up)
            figures[f"cpu_ms_per_image_{label}"] = round(1000 * (cpu() - before) / images, 2)
    return figures


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=100)
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="image_writes_"))
    servers = {"pouchdb-server": PouchDBServer(work / "pouchdb").start()}
    shared = shared_couchdb_dir(ROOT)
    if missing_reason(shared) is None:
        servers["Apache CouchDB 3.5"] = ApacheCouchDB(shared, work / "apache").start()
    else:
        print(f"skipping Apache CouchDB: {missing_reason(shared)}", file=sys.stderr)
    result = {}
    try:
        for name, server in servers.items():
            for index, way in enumerate(WAYS):
                database = f"images_{index}"
                # pouchdb-server: the store creates it; Apache CouchDB: the admin, with the member
                url = server.database_url(database)
                result[f"{name}, {way}"] = run_way(url, way, args.images, 1.7e9 + 100 * index)
                print(json.dumps({f"{name}, {way}": result[f"{name}, {way}"]}), flush=True)
    finally:
        for server in servers.values():
            server.stop()
    out = ROOT / "artifacts" / "bench" / "image_writes.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
