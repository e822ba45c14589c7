"""MongoDB with least-privilege accounts, lost cursors, write concerns and wide integers.

nx-27017 (the real wire-protocol server here) has no accounts and ends a killed cursor silently,
where mongod answers 13 Unauthorized / 43 CursorNotFound. Those answers come from a real process
in between: mongo_fault_proxy.py, a TCP-level wire-protocol proxy that forwards everything and
answers the refused commands itself exactly as mongod does.
"""
import subprocess
import sys
from io import BytesIO
from pathlib import Path

import genpy
import pymongo
import pytest
from std_msgs.msg import String, UInt64

from ros_harness import ManagedProcess, wait_until
from ros_mongo import open_store
from ros_mongo.files.bagio import export_bag, iter_bag
from ros_mongo.query import Query
from ros_mongo.records import TopicInfo, make_record
from ros_mongo.replay.replay import Replayer
from ros_mongo.storage.mongo import INDEXES

pytestmark = pytest.mark.db

PROXY = Path(__file__).resolve().parent / "mongo_fault_proxy.py"
N = 1234


class MongoFaultProxy:
    """mongo_fault_proxy.py as a managed child process in front of `upstream` (host:port)."""

    def __init__(self, upstream: str, mode: str, workdir: Path):
        self.ready = workdir / f"proxy_{mode}.port"
        self.log = workdir / f"proxy_{mode}.refused"
        argv = [sys.executable, str(PROXY), "--upstream", upstream, "--mode", mode,
                "--ready", str(self.ready), "--log", str(self.log)]
        self.process = ManagedProcess(argv, name=f"mongo fault proxy ({mode})",
                                      log_path=workdir / f"proxy_{mode}.log")

    def start(self) -> "MongoFaultProxy":
        self.process.start()
        wait_until(self.ready.exists, 30, what="the fault proxy's port", check=self.process.check_alive)
        self.port = int(self.ready.read_text())
        return self

    def url(self, db: str) -> str:
        return f"mongodb://127.0.0.1:{self.port}/{db}"

    def refused(self):
        return self.log.read_text().split() if self.log.exists() else []

    def stop(self) -> None:
        self.process.stop(timeout=10)


@pytest.fixture
def proxy_factory(mongodb_server, tmp_path):
    proxies = []

    def make(mode: str) -> MongoFaultProxy:
        proxy = MongoFaultProxy(f"127.0.0.1:{mongodb_server.port}", mode, tmp_path).start()
        proxies.append(proxy)
        return proxy
    yield make
    for proxy in proxies:
        proxy.stop()


def _fill(url: str, count: int = N):
    """`count` messages on two topics, several sharing one receive time (ties broken by id)."""
    infos = [TopicInfo.of_class("/chatter", String), TopicInfo.of_class("/other", String)]
    records = []
    for i in range(count):
        topic = "/chatter" if i % 3 else "/other"
        raw = String(data=f"m{i}")
        records.append(make_record(topic, String, _raw(raw), receive=genpy.Time(1_700_000_000 + i // 4, 0),
                                   robot_id="r1"))
    with open_store(url) as store:
        for info in infos:
            store.put_topic(info)
        assert store.insert_records(records) == count
    return records


def _raw(msg) -> bytes:
    buffer = BytesIO()
    msg.serialize(buffer)
    return buffer.getvalue()


def _expected_order(records):
    return [r.id for r in sorted(records, key=lambda r: (r.receive_time, r.id))]


def test_read_only_account_can_query_replay_and_export(mongodb_url, proxy_factory, tmp_path):
    records = _fill(mongodb_url)
    proxy = proxy_factory("read_only")
    db = mongodb_url.rsplit("/", 1)[1]
    with open_store(proxy.url(db)) as reader:
        assert reader.count() == N
        assert [m.id for m in reader.find(Query())] == _expected_order(records)
        others = _expected_order([r for r in records if r.topic == "/other"])
        assert [m.id for m in reader.find(Query(topics=["/other"]), newest_first=True, limit=5)] == \
            others[::-1][:5]
        result = export_bag(reader, Query(), tmp_path / "out.bag", progress=False)
        assert result.messages == N
        written = list(iter_bag(tmp_path / "out.bag"))
        for topic in ("/chatter", "/other"):  # a bag orders ties between topics its own way
            assert [(raw, stamp) for t, raw, stamp, _ in written if t == topic] == \
                [(r.raw, genpy.Time(r.receive_secs, r.receive_nsecs))
                 for r in sorted(records, key=lambda r: (r.receive_time, r.id)) if r.topic == topic]
        played = []
        replayer = Replayer(reader, played.append, fixed_rate=100000.0)
        replayer.start(Query(topics=["/chatter"]))
        assert replayer.wait(120), "the replay did not finish"
        assert replayer.state == "finished", replayer.error
        in_order = sorted(records, key=lambda r: (r.receive_time, r.id))
        assert [p.raw for p in played] == [r.raw for r in in_order if r.topic == "/chatter"]
        # and writing is refused as the operator's problem, naming the refusal, not the password
        with pytest.raises(Exception) as refused:
            reader.insert_records([make_record("/chatter", String, _raw(String(data="x")),
                                               receive=genpy.Time(1, 0))])
        assert "not authorized" in str(refused.value) and type(refused.value).__name__ == "StoreRefused"
    # reading never asked for an index or any write: only the final write attempt did
    assert proxy.refused() and set(proxy.refused()) <= {"createIndexes", "insert"}


def test_reads_never_create_indexes(mongodb_url, proxy_factory):
    _fill(mongodb_url, 50)
    direct = pymongo.MongoClient(mongodb_url)
    db = direct.get_default_database()
    for name in list(db.messages.index_information()):
        if name != "_id_":
            db.messages.drop_index(name)
    proxy = proxy_factory("read_only")
    with open_store(proxy.url(db.name)) as reader:
        assert reader.count(Query(topics=["/chatter"])) == sum(1 for i in range(50) if i % 3)
        assert len(list(reader.find(Query(), limit=10))) == 10
        reader.topics()
    assert proxy.refused() == []
    assert list(db.messages.index_information()) == ["_id_"]
    direct.close()


def test_writer_without_index_rights_records_and_setup_creates_them(mongodb_url, proxy_factory):
    proxy = proxy_factory("no_index")
    db = mongodb_url.rsplit("/", 1)[1]
    records = _fill(proxy.url(db), 40)
    assert "createIndexes" in proxy.refused()
    direct = pymongo.MongoClient(mongodb_url)
    keys = [list(i["key"].items()) for i in direct.get_default_database().messages.list_indexes()]
    assert keys == [[("_id", 1)]]
    cli = [sys.executable, "-c", "import sys; from ros_mongo.cli import main; sys.exit(main())"]
    refused = subprocess.run(cli + ["setup", "--db-url", proxy.url(db)], capture_output=True, text=True,
                             timeout=120)
    assert refused.returncode == 1 and "may not create indexes" in refused.stderr, refused.stderr
    done = subprocess.run(cli + ["setup", "--db-url", mongodb_url], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    keys = [[(k, int(d)) for k, d in i["key"].items()]
            for i in direct.get_default_database().messages.list_indexes()]
    for wanted in INDEXES.values():
        assert [(k, d) for k, d in wanted] in keys
    with open_store(mongodb_url) as store:
        assert [m.id for m in store.find(Query())] == _expected_order(records)
    direct.close()


def test_a_lost_cursor_is_replaced_without_losing_or_repeating(mongodb_url, proxy_factory, tmp_path):
    records = _fill(mongodb_url)
    proxy = proxy_factory("lose_cursors")
    db = mongodb_url.rsplit("/", 1)[1]
    with open_store(proxy.url(db)) as reader:
        got = [m.id for m in reader.find(Query())]
        assert got == _expected_order(records)
        assert [m.id for m in reader.find(Query(), newest_first=True)] == got[::-1]
        assert reader.count() == N
        played = []
        replayer = Replayer(reader, played.append, fixed_rate=100000.0)
        replayer.start(Query())
        assert replayer.wait(120) and replayer.state == "finished", replayer.error
        assert [p.raw for p in played] == [next(r for r in records if r.id == i).raw for i in got]
    assert proxy.refused().count("getMore") >= 2, "the test never made the server lose a cursor"


@pytest.mark.parametrize("options, expected", [
    ("", {"w": 1, "j": True}),
    ("?w=majority", {"w": "majority"}),
    ("?journal=false&w=1", {"w": 1, "j": False}),
    ("?w=majority&wtimeoutMS=5000", {"w": "majority", "wtimeout": 5000}),
])
def test_write_concern_of_the_url_is_kept(mongodb_url, options, expected):
    with open_store(mongodb_url + options) as store:
        assert store.messages.write_concern.document == expected
        _ = store.insert_records([make_record("/chatter", String, _raw(String(data="x")),
                                              receive=genpy.Time(5, 0))])
        assert store.count() == 1


def test_uint64_above_int64_round_trips_on_both_backends(db_url):
    big = 2 ** 64 - 1
    with open_store(db_url) as store:
        store.insert_message("/big", UInt64(data=big), receive_time=10.0)
        store.insert_message("/big", UInt64(data=2 ** 63 + 12345), receive_time=11.0)
        stored = list(store.find(Query(topics=["/big"])))
    assert [m.message().data for m in stored] == [big, 2 ** 63 + 12345]  # the exact bytes
    # the decoded field holds the nearest double on both backends (BSON holds no wider integer; a
    # JavaScript CouchDB look-alike writes it back without ".0", so compare numbers)
    assert [float(m.fields["data"]) for m in stored] == [float(big), float(2 ** 63 + 12345)]
    with open_store(db_url) as store:
        query = Query.build(topic="/big", fields={"data": {"$gt": 9.3e18}})
        assert [m.message().data for m in store.find(query)] == [big]


def test_an_integer_beyond_64_bits_in_fields_is_refused_clearly_and_alone(mongodb_url):
    good = make_record("/chatter", String, _raw(String(data="ok")), receive=genpy.Time(7, 0))
    bad = make_record("/chatter", String, _raw(String(data="bad")), receive=genpy.Time(8, 0))
    bad.fields = {"data": 2 ** 70}
    with open_store(mongodb_url) as store:
        with pytest.raises(Exception) as err:
            store.insert_records([good, bad])
        assert type(err.value).__name__ == "DocumentsRejected"
        assert bad.id in str(err.value) and "BSON" in str(err.value)
        assert [m.id for m in store.find(Query())] == [good.id]
