"""Chunked topics (ros_mongo.storage.chunks): many small messages of a topic in one CouchDB document, read
back message by message (real pouchdb-server through the couchdb fixtures, no ROS)."""
import io
import sys
import time
from pathlib import Path

import genpy
import pytest
import requests
import rosbag
from nav_msgs.msg import Odometry
from ros_mongo_samples import serialized
from sharded_feed_proxy import shard_of
from std_msgs.msg import String

from ros_harness import FaultProxy, ManagedProcess, wait_until
from ros_mongo import open_store
from ros_mongo.files.bagio import export_file
from ros_mongo.fleet.changes import ChangesFollower
from ros_mongo.query import Query
from ros_mongo.recording.bounded_spool import BoundedSpool
from ros_mongo.recording.chunker import Chunker, ChunkPolicy
from ros_mongo.recording.recorder import Recorder
from ros_mongo.recording.spool import _read_frame, frames, read_entries
from ros_mongo.records import make_record, new_message_id, split_time
from ros_mongo.replay.replay import Replayer
from ros_mongo.storage.chunks import CHUNK_SPAN, ChunkRecord
from ros_mongo.storage.couch import field_matcher

T0 = 1700000000.0
N = 2300          # /odom at 1 kHz: 2.3 s, so chunks close by time and by count
EVERY = 50        # one /chatter message (a document of its own) per 50 odometry messages
SHARDED_FEED_PROXY = Path(__file__).resolve().parent / "sharded_feed_proxy.py"


def _odom(i):
    msg = Odometry()
    msg.header.seq, msg.header.stamp, msg.header.frame_id = i, genpy.Time(500 + i), str(i)
    msg.pose.pose.position.x = float(i)
    return msg


def _receive_all(recorder):
    """What the test publishes: (topic, receive time, exact bytes) in receive order."""
    sent = []
    for i in range(N):
        stamp = T0 + i * 1e-3
        raw = serialized(_odom(i))
        recorder.receive("/odom", raw, split_time(stamp), Odometry._type, Odometry._md5sum,
                         Odometry._full_text)
        sent.append(("/odom", split_time(stamp), raw))
        if i % EVERY == 0:
            raw = serialized(String(data=f"c{i}"))
            stamp += 0.0005
            recorder.receive("/chatter", raw, split_time(stamp), String._type, String._md5sum,
                             String._full_text)
            sent.append(("/chatter", split_time(stamp), raw))
    return sent


def _record(url, tmp_path, **options):
    with open_store(url) as store:
        spool = BoundedSpool(tmp_path / "rec.spool", min_free_bytes=0).open()
        recorder = Recorder(store, spool, batch_period=0.05, robot_id="r1",
                            chunks=ChunkPolicy(["/odom"], max_messages=400), **options).start()
        sent = _receive_all(recorder)
        counts = recorder.stop(timeout=120)
        spool.close()
    return sent, counts


def _documents(url):
    rows = requests.get(f"{url}/_all_docs", params={"include_docs": "true"}, timeout=60).json()["rows"]
    return [row["doc"] for row in rows if not row["id"].startswith("_design/")]


def test_chunker_closes_by_span_count_and_time_going_back():
    chunker = Chunker(max_messages=3)
    key = ("/odom", "t", "m", "")
    assert chunker.add(key, b"a", 10, 0, now=0.0) == []
    closed = chunker.add(key, b"b", 10 + int(CHUNK_SPAN), 0, now=0.0)   # a span after the first
    assert [c.raws for c in closed] == [[b"a"]]
    assert chunker.add(key, b"c", 11, 5, now=0.0) == []
    assert [c.raws for c in chunker.add(key, b"d", 11, 6, now=0.0)] == [[b"b", b"c", b"d"]]  # count
    chunker.add(key, b"e", 12, 0, now=0.0)
    assert [c.raws for c in chunker.add(key, b"f", 11, 0, now=0.0)] == [[b"e"]]  # time went back
    assert chunker.due(now=CHUNK_SPAN / 2) == [] and len(chunker.due(now=CHUNK_SPAN)) == 1


def test_field_conditions_on_chunk_messages_mean_what_the_servers_make_them_mean():
    """A chunk's messages are matched with the selector the server gets for message documents
    (ros_mongo.storage.documents), evaluated as Apache CouchDB does (ros_mongo.storage.mango)."""
    fields = {"a": 1, "s": "x", "arr": [1.0, 5.0], "inf": "Infinity", "nan": "NaN", "n": None}

    def fields_match(msg, conditions):
        return field_matcher(Query(fields=conditions))({"kind": "message", "msg": msg})

    assert fields_match(fields, {"a": {"$eq": 1}}) and not fields_match(fields, {"a": {"$eq": True}})
    assert not fields_match(fields, {"a": {"$eq": "1"}}) and fields_match(fields, {"arr": {"$eq": 5.0}})
    assert fields_match(fields, {"missing": {"$eq": None}})
    assert fields_match(fields, {"n": {"$exists": False}})
    assert fields_match(fields, {"missing": {"$ne": 3}}) and not fields_match(fields, {"arr": {"$ne": 1.0}})
    assert fields_match(fields, {"arr": {"$gte": 4.0, "$lte": 6.0}})
    assert not fields_match(fields, {"arr": {"$gt": 1.0, "$lt": 5.0}})   # no element holds both
    assert fields_match(fields, {"inf": {"$gt": 1e308}})
    assert not fields_match(fields, {"nan": {"$gt": -1e308}})
    assert fields_match(fields, {"s": {"$in": ["y", "x"]}}) and not fields_match(fields, {"s": {"$gt": 1}})
    assert fields_match(fields, {"a": {"$nin": [2, 3]}}) and not fields_match(None, {"a": {"$exists": True}})


@pytest.mark.db
def test_chunked_topic_round_trip_queries_export_and_replay(couchdb_url, tmp_path):
    sent, counts = _record(couchdb_url, tmp_path)
    assert counts["stored"] == len(sent) and counts["dropped"] == 0, counts
    docs = _documents(couchdb_url)
    chunks = [d for d in docs if d.get("kind") == "chunk"]
    assert {d["topic"] for d in chunks} == {"/odom"}
    assert 6 <= len(chunks) <= 12                      # 400 at most, 1 s at most each
    assert sum(d["count"] for d in chunks) == N
    assert not any(d.get("kind") == "message" and d["topic"] == "/odom" for d in docs)

    with open_store(couchdb_url) as store:
        got = list(store.find(Query()))
        # every message once, in receive order, its exact bytes, ids unique
        assert [(m.topic, m.receive_stamp, m.raw) for m in got] == sorted(sent, key=lambda s: s[1])
        assert len({m.id for m in got}) == len(sent)
        assert all(m.robot_id == "r1" for m in got)
        odom = [m for m in got if m.topic == "/odom"]
        assert [m.message().header.frame_id for m in odom] == [str(i) for i in range(N)]
        assert [m.header_stamp for m in odom[:3]] == [500.0, 501.0, 502.0]
        assert store.count(Query(topics=["/odom"])) == N
        # a time range starting and ending inside chunks: exactly the messages in it
        start, end = T0 + 0.4505, T0 + 1.2004
        ranged = list(store.find_messages(topic="/odom", start_time=start, end_time=end))
        assert [m.message().header.seq for m in ranged] == list(range(451, 1201))
        assert store.count_messages(topic="/odom", start_time=start, end_time=end) == 750
        both = list(store.find_messages(topic=["/odom", "/chatter"], start_time=start, end_time=end))
        assert [m.receive_stamp for m in both] == sorted(s[1] for s in sent if start <= s[1].to_sec() <= end)
        # field queries on a chunked topic: checked message by message
        hits = list(store.find_messages(topic="/odom", fields={"pose.pose.position.x": [99.5, 103.0]}))
        assert [m.message().header.seq for m in hits] == [100, 101, 102, 103]
        sevens = store.find_messages(fields={"header.frame_id": "7"})
        assert [m.fields["header"]["frame_id"] for m in sevens] == ["7"]
        newest = list(store.find_messages(topic="/odom", newest_first=True, limit=3))
        assert [m.message().header.seq for m in newest] == [N - 1, N - 2, N - 3]
        # bag export: every message, its bytes and receive time
        export_file(store, Query(), tmp_path / "out.bag")
        with rosbag.Bag(str(tmp_path / "out.bag")) as bag:
            exported = [(t, stamp, raw[1]) for t, raw, stamp in bag.read_messages(raw=True)]
        assert exported == sorted(sent, key=lambda s: s[1])

        # replay: every message in recorded order, spread over (most of) the recorded span
        played = []
        replayer = Replayer(store, played.append, preroll_timeout=60.0)
        began = time.monotonic()
        replayer.start(Query(topics=["/odom"], start_time=T0, end_time=T0 + 0.8))
        assert replayer.wait(120)
        took = time.monotonic() - began
    assert replayer.state == "finished", replayer.error
    expected = [s[2] for s in sent if s[0] == "/odom" and s[1].to_sec() <= T0 + 0.8]
    assert [item.raw for item in played] == expected
    assert took >= 0.75 * 0.8


@pytest.mark.db
def test_changes_follower_yields_each_message_of_a_chunk_and_resumes_inside_one(couchdb_url, tmp_path):
    sent, _ = _record(couchdb_url, tmp_path)
    with open_store(couchdb_url) as store:
        ids = [m.id for m in store.find_messages(topic="/odom")]
    follower = ChangesFollower(couchdb_url, selector={"topic": "/odom"}, page=5)
    got = []
    while not follower.caught_up:
        got += follower.poll()
    # each message once, its id and bytes (Apache CouchDB's feed interleaves its shards: a chunk's
    # messages come in order, chunks in the feed's order)
    assert sorted(item.message.id for item in got) == ids
    by_id = {m.id: m.raw for m in got_messages(couchdb_url)}
    assert all(item.message.raw == by_id[item.message.id] for item in got)
    assert sorted(item.message.raw for item in got) == sorted(s[2] for s in sent if s[0] == "/odom")
    assert {item.message.robot_id for item in got} == {"r1"}
    # resuming from a position inside a chunk yields the rest, nothing twice
    cut = 555
    assert isinstance(got[cut].seq, dict)
    again = ChangesFollower(couchdb_url, selector={"topic": "/odom"}, since=got[cut].seq, page=5)
    rest = []
    while not again.caught_up:
        rest += again.poll()
    rest_ids = [item.message.id for item in rest]
    assert sorted(rest_ids) == sorted(item.message.id for item in got[cut + 1:])
    # ... each chunk's messages in one run, in order; the chunks themselves may come in another
    # order than in the first feed (Apache CouchDB interleaves its shards anew on each request)
    chunk_of, chunk = [], 0
    for item in got:
        chunk_of.append(chunk)
        chunk += not isinstance(item.seq, dict)     # a chunk's last message has a plain seq
    place = {item.message.id: n for n, item in enumerate(got)}
    order = [place[i] for i in rest_ids]
    runs = 1 + sum(1 for a, b in zip(order, order[1:]) if not (b == a + 1 and chunk_of[a] == chunk_of[b]))
    assert runs == len({chunk_of[n] for n in order}), "a chunk's messages split or out of order"
    follower.close()
    again.close()


@pytest.fixture
def sharded_feed(couchdb_server, tmp_path):
    """sharded_feed_proxy.py (a real process) in front of pouchdb-server: its `_changes` feed as
    Apache CouchDB's two shards can order it; the proxy's root URL (then /<order>/<db>)."""
    ready = tmp_path / "sharded_feed.port"
    process = ManagedProcess([sys.executable, str(SHARDED_FEED_PROXY), "--upstream", couchdb_server.url,
                              "--ready", str(ready)], name="sharded feed proxy",
                             log_path=tmp_path / "sharded_feed.log").start()
    try:
        wait_until(ready.exists, 60, what="the sharded feed proxy's port", check=process.check_alive)
        yield f"http://127.0.0.1:{int(ready.read_text())}"
    finally:
        process.stop(timeout=10)


def _small_and_chunked(store):
    """40 /chatter documents, one chunk of 100 /odom messages, 40 more /chatter documents, in
    that order, with fixed ids (so the proxy's shards are the same on every run): the ids of
    the chatter documents and of the chunk's messages."""
    def record(topic, msg, stamp, number):
        receive = split_time(stamp)
        fixed = new_message_id(receive.secs, receive.nsecs, "r1", token=f"{number:012x}")
        return make_record(topic, type(msg), serialized(msg), receive=receive, robot_id="r1",
                           record_id=fixed)
    chatter = [record("/chatter", String(data=str(i)), T0 + i, i) for i in range(80)]
    odom = [record("/odom", _odom(i), T0 + 39.5 + i * 1e-3, 100 + i) for i in range(100)]
    for entries in (chatter[:40], [ChunkRecord(odom)], chatter[40:]):
        assert store.insert_records(entries) == len(entries)
    return [r.id for r in chatter], [r.id for r in odom]


@pytest.mark.db
def test_changes_follower_resumes_inside_a_chunk_that_another_shards_changes_overtake(couchdb_server,
                                                                                      sharded_feed):
    """Apache CouchDB (q = 2) passes its shards' changes on as they reach it, anew on each
    request: after a resume, one shard's changes may fill a page before the next change of the
    other comes (a real node under load once made a follower resumed inside a chunk yield the
    chunk's first messages again). sharded_feed_proxy.py, in front of pouchdb-server, serves its
    feed as two shards: read in write order, resumed with the chunk's shard answering last."""
    name = "overtaken_chunk"
    with open_store(couchdb_server.database_url(name)) as store:
        chatter_ids, chunk_ids = _small_and_chunked(store)
    follower = ChangesFollower(f"{sharded_feed}/fair/{name}", page=3)
    got = []
    while not follower.caught_up:
        got += follower.poll()
    follower.close()
    ids = [item.message.id for item in got]
    # pouchdb-server's order: the writes in order (a batch's documents in any order)
    assert sorted(ids[:40]) == chatter_ids[:40] and sorted(ids[140:]) == chatter_ids[40:]
    assert ids[40:140] == chunk_ids
    cut = 40 + 39                                       # 40 of the chunk's 100 messages yielded
    chunk = chunk_ids[0] + ".chunk"
    assert got[cut].seq["chunk"] == chunk and got[cut].seq["done"] == 40
    # the fault: from the feed position before the chunk, the other shard's documents fill a
    # page of 3 and the chunk comes in a later page
    slow = f"{sharded_feed}/slow{shard_of(chunk)}/{name}"
    before = got[39].seq
    page = requests.get(f"{slow}/_changes", params={"since": before, "limit": 3, "include_docs": "true"},
                        timeout=60).json()
    assert len(page["results"]) == 3 and chunk not in [row["id"] for row in page["results"]]
    # resuming from the position (and from one as an earlier release saved it, holding the feed
    # position before the chunk): nothing twice, nothing lost; the chunk's other 60 messages
    # first, in order, then the rest of the feed
    for since in (got[cut].seq, {"since": before, "chunk": chunk, "done": 40}):
        again = ChangesFollower(slow, since=since, page=3)
        rest = []
        while not again.caught_up:
            rest += again.poll()
        again.close()
        rest_ids = [item.message.id for item in rest]
        assert sorted(rest_ids) == sorted(ids[cut + 1:])
        assert rest_ids[:60] == chunk_ids[40:]


@pytest.mark.db
def test_chunks_are_stored_once_through_retries_an_outage_and_a_restart(couchdb_server, tmp_path):
    name = "chunks_outage"
    url = couchdb_server.database_url(name)
    with FaultProxy(couchdb_server.url, tmp_path) as proxy, open_store(proxy.database_url(name)) as store:
        store.connect()
        proxy.set(timeout="writes")          # central answers 500 timeout: everything is spooled
        spool = BoundedSpool(tmp_path / "rec.spool", min_free_bytes=0).open()
        recorder = Recorder(store, spool, batch_period=0.05, retry_period=0.2, robot_id="r1",
                            chunks=ChunkPolicy(["/odom"], max_messages=400)).start()
        sent = _receive_all(recorder)
        counts = recorder.stop(timeout=3)    # the robot stops while central is down
        spool.close()
        assert counts["stored"] == 0 and counts["spool_pending"] == len(sent), counts
    entries = read_entries(tmp_path / "rec.spool")
    spooled = [e for e in entries if isinstance(e, ChunkRecord)]
    assert sum(c.count for c in spooled) == N
    assert _frame_round_trip(spooled[0])
    with open_store(url) as store:
        # a write whose answer was lost: the first chunk is on central already
        assert store.insert_records([spooled[0]]) == 1
        assert store.insert_records([spooled[0]]) == 0        # sent again: stored once
        spool = BoundedSpool(tmp_path / "rec.spool", min_free_bytes=0).open()
        again = Recorder(store, spool, batch_period=0.05, retry_period=0.2, robot_id="r1",
                         chunks=ChunkPolicy(["/odom"])).start()    # a new recorder drains the spool
        wait_until(lambda: again.counts()["spool_pending"] == 0, 120, what="the spool to drain")
        again.stop(timeout=30)
        spool.close()
        got = list(store.find(Query()))
    assert [(m.topic, m.receive_stamp, m.raw) for m in got] == sorted(sent, key=lambda s: s[1])
    chunk_ids = [d["_id"] for d in _documents(url) if d.get("kind") == "chunk"]
    assert sorted(chunk_ids) == sorted(c.id for c in spooled)


def got_messages(url):
    with open_store(url) as store:
        return list(store.find_messages(topic="/odom"))


def _frame_round_trip(chunk):
    """A chunk's spool frame reads back as the same records."""
    data, count = frames([chunk])
    back, _ = _read_frame(io.BytesIO(data))
    return count == chunk.count and [vars(r) for r in back.records] == [vars(r) for r in chunk.records]


@pytest.mark.db
def test_recorder_without_chunk_topics_writes_a_document_per_message(couchdb_url, tmp_path):
    with open_store(couchdb_url) as store:
        spool = BoundedSpool(tmp_path / "rec.spool", min_free_bytes=0).open()
        recorder = Recorder(store, spool, batch_period=0.05, chunks=ChunkPolicy()).start()
        for i in range(20):
            raw = serialized(String(data=str(i)))
            recorder.receive("/chatter", raw, split_time(T0 + i), String._type, String._md5sum,
                             String._full_text)
        recorder.stop(timeout=60)
        spool.close()
    kinds = [d.get("kind") for d in _documents(couchdb_url)]
    assert kinds.count("message") == 20 and "chunk" not in kinds


def test_chunk_rate_threshold_picks_high_rate_topics():
    policy = ChunkPolicy(min_rate=100)
    slow = [policy.chunked("/slow", 10 + 0.1 * i) for i in range(50)]
    fast = [policy.chunked("/fast", 10 + 0.001 * i) for i in range(150)]
    assert not any(slow)
    assert not any(fast[:99]) and all(fast[99:])

