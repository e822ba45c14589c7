"""What a real Apache CouchDB 3 answers and pouchdb-server never does: accounts, size limits,
cluster timeouts and quorum, cut-off bodies, latency, a reverse proxy's path prefix.

These answers come from ros_harness.fault_proxy: a REAL process on its own port in front of a real
pouchdb-server, answering with the exact status and JSON bodies a real CouchDB 3.5 gave (as
measured against one), switched on and off while the real
recorder node (roscore + roslaunch) runs. The member-account and document-size tests run on the
real Apache CouchDB too (`member`, `size_limit`: its own refusals, no proxy). Expected values come
from what the test published, never from the code under test.
"""
import json
import subprocess
import threading
import uuid
from typing import Callable, NamedTuple, Optional

import pytest
import requests
import rospy
from diagnostic_msgs.msg import DiagnosticStatus
from recorder_harness import Sender, start_recorder, stored_xs
from ros_mongo_samples import serialized
from std_msgs.msg import String

from ros_harness import FaultProxy, wait_for_subscriber, wait_until
from ros_mongo import TopicInfo, make_record, open_store
from ros_mongo.errors import StoreError, StoreRefused
from ros_mongo.files.bagio import export_bag
from ros_mongo.query import parse_query
from ros_mongo.recording.bounded_spool import BoundedSpool
from ros_mongo.recording.quarantine import import_quarantine
from ros_mongo.recording.recorder import Recorder
from ros_mongo.recording.spool import read_entries
from ros_mongo.records import MessageRecord, split_time

pytestmark = [pytest.mark.db]


@pytest.fixture
def proxy(couchdb_server, tmp_path):
    with FaultProxy(couchdb_server.url, tmp_path) as running:
        yield running


@pytest.fixture
def prefixed_proxy(couchdb_server, tmp_path):
    with FaultProxy(couchdb_server.url, tmp_path, prefix="/couchdb") as running:
        yield running


def _names(prefix="test_"):
    return prefix + uuid.uuid4().hex[:12]


def _admin_creates(couchdb_server, name):
    """The admin's step: the database exists before the member account records into it."""
    assert requests.put(f"{couchdb_server.url}/{name}", timeout=30).status_code in (201, 202)


class Member(NamedTuple):
    """A database an admin created, as its member sees it (`url`) and as the admin does (`admin`);
    `new(name)`: the member's URL of a database nobody created; `proxy` (pouchdb-server only)."""

    url: str
    admin: str
    new: Callable[[str], str]
    proxy: Optional[FaultProxy]


@pytest.fixture(params=["pouchdb", "apache"])
def member(request, tmp_path):
    """A member account: pouchdb-server behind the proxy answering as CouchDB 3 does for members,
    then the real thing (a real Apache CouchDB node, its admin and member accounts)."""
    name = _names()
    if request.param == "apache":
        server = request.getfixturevalue("apache_couchdb")
        yield Member(server.database_url(name), server.admin_database_url(name), server.member_url, None)
        return
    server = request.getfixturevalue("couchdb_server")
    _admin_creates(server, name)
    with FaultProxy(server.url, tmp_path) as proxy:
        proxy.set(member=True)
        yield Member(proxy.database_url(name), f"{server.url}/{name}", proxy.database_url, proxy)


def _records(count, t0=1000.0, topic="/chatter", step=0.01):
    return [make_record(topic, String, serialized(String(data=f"m{i}")), receive=split_time(t0 + step * i),
                        session_id="s1") for i in range(count)]


# -- the store on its own (no ROS) -------------------------------------------------------------------
def test_member_account_records_and_reads_without_any_design_document(member, tmp_path):
    records = _records(700)
    with open_store(member.url) as store:
        assert store.indexed is False                 # the _index POST was refused as for a member
        store.put_topic(TopicInfo.of_class("/chatter", String))
        assert store.insert_records(records) == 700
        got = [m.message().data for m in store.find_messages(topic="/chatter")]
        assert got == [f"m{i}" for i in range(700)]
        newest = [m.message().data for m in store.find_messages(newest_first=True, limit=3)]
        assert newest == ["m699", "m698", "m697"]
        window = [m.message().data for m in store.find_messages(start_time=1001.0, end_time=1001.05)]
        assert window == [f"m{i}" for i in range(100, 106)]
        assert store.count_messages(topic="/chatter") == 700
        result = export_bag(store, parse_query("topic /chatter"), tmp_path / "out.bag", progress=False)
        assert result.messages == 700
    assert member.proxy is None or member.proxy.answered("member") >= 1
    design = requests.get(f"{member.admin}/_all_docs",
                          params={"startkey": '"_design/"', "endkey": '"_design0"'}, timeout=30).json()
    assert design["rows"] == []                       # nothing an admin would have to write


def test_member_cannot_create_the_database_and_is_told_so(member):
    with pytest.raises(StoreRefused) as err:
        open_store(member.new(_names()))
    assert "may not create it" in str(err.value) and "You are not a server admin." in str(err.value)


def test_index_created_by_another_robot_at_the_same_time_is_tolerated(couchdb_server, proxy):
    proxy.set(index_conflict=True)
    with open_store(proxy.database_url(_names())) as store:
        assert store.indexed is True
    assert proxy.answered("index_conflict") >= 1


def test_prefix_latency_truncated_bodies_and_202_quorum(couchdb_server, prefixed_proxy):
    name = _names()
    url = prefixed_proxy.database_url(name)           # http://127.0.0.1:PORT/couchdb/<name>
    with open_store(url, page_size=100) as store:
        store.put_topic(TopicInfo.of_class("/chatter", String))
        prefixed_proxy.set(accepted_202=True)
        assert store.insert_records(_records(300)) == 300     # 202: checked, all readable
        prefixed_proxy.set(truncate_find=2, latency=0.6)
        got = [m.message().data for m in store.find_messages(topic="/chatter")]
    assert got == [f"m{i}" for i in range(300)]               # the cut-off pages were read again
    assert prefixed_proxy.answered("truncate_find") == 2 and prefixed_proxy.answered("accepted_202") >= 1
    rows = requests.get(f"{couchdb_server.url}/{name}/_all_docs", timeout=30).json()["rows"]
    assert len([r for r in rows if r["id"][0].isdigit()]) == 300  # each message once


def test_windowed_reader_keeps_advancing_on_a_slow_link(couchdb_server, proxy):
    """A query the index does not answer alone is read in time windows; 600 ms per answer must not
    shrink them until reading stops advancing."""
    with open_store(proxy.database_url(_names())) as store:
        store.put_topic(TopicInfo.of_class("/chatter", String))
        store.insert_records(_records(120, step=0.5))            # 60 s of sparse messages
        proxy.set(latency=0.6)
        got = []
        reader = threading.Thread(target=lambda: got.extend(
            m.message().data for m in store.find_messages(topic="/chatter", session_id="s1")), daemon=True)
        reader.start()
        reader.join(240)
    assert got == [f"m{i}" for i in range(120)]


# -- the recorder node through the proxy --------------------------------------------------------------
def recorder(roslaunch, url, tmp_path, **params):
    """The recorder node with a longer database timeout (the proxy delays answers)."""
    return start_recorder(roslaunch, url, tmp_path, **{"db_timeout": 10.0, "session_id": "faults", **params})


FAULTS = {
    "operator fixes the password": {"auth": "wrong_password"},
    "server recovers from timeouts": {"timeout": "writes"},
    "member account, password rotated": {"member": True, "auth": "wrong_password"},
}


@pytest.mark.ros
@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_recorder_keeps_every_message_through_a_fault_and_stores_each_once(
        couchdb_server, proxy, roslaunch, tmp_path, diagnostics, fault):
    name = _names()
    _admin_creates(couchdb_server, name)
    if FAULTS[fault].get("member"):
        proxy.set(member=True)
    launch = recorder(roslaunch, proxy.database_url(name), tmp_path)
    sender = Sender(rate=500.0).connected(launch.node_name)
    sender.send(100)
    wait_until(lambda: diagnostics.count("stored") == 100, 60, what="100 stored")
    proxy.set(**FAULTS[fault])
    sender.send(200)
    wait_until(lambda: diagnostics.count("spool_pending") == 200, 60, what="200 spooled")
    key = "auth" if "auth" in FAULTS[fault] else "timeout"
    reason = "Name or password is incorrect." if key == "auth" else "timeout"
    wait_until(lambda: diagnostics.level == DiagnosticStatus.ERROR and reason in diagnostics.message, 60,
               what="ERROR on /diagnostics with the server's reason")
    assert proxy.answered(key) >= 1 and diagnostics.count("stored") == 100
    proxy.set(member=True) if FAULTS[fault].get("member") else proxy.clear()
    wait_until(lambda: diagnostics.count("stored") == 300 and diagnostics.count("spool_pending") == 0, 90,
               what="the spool drained")
    assert stored_xs(f"{couchdb_server.url}/{name}") == [float(i) for i in range(300)]
    assert diagnostics.count("dropped") == 0 and diagnostics.count("rejected") == 0
    wait_until(lambda: diagnostics.level == DiagnosticStatus.OK, 90, what="OK once writes work")
    assert "secret" not in str(diagnostics.values)
    sender.close()


@pytest.mark.ros
def test_rotated_password_then_fixed_by_the_operator_with_a_credentials_file(
        couchdb_server, proxy, roslaunch, tmp_path, diagnostics):
    name = _names()
    secret = "Pw-" + uuid.uuid4().hex[:10]
    credentials = tmp_path / "db_credentials"
    credentials.write_text(f"robot:{secret}\n")
    proxy.set(require_auth=f"robot:{secret}")
    launch = recorder(roslaunch, proxy.database_url(name), tmp_path, db_credentials_file=str(credentials))
    sender = Sender(rate=500.0).connected(launch.node_name)
    sender.send(100)
    wait_until(lambda: diagnostics.count("stored") == 100, 60, what="100 stored")
    proxy.set(require_auth="robot:rotated-by-someone")     # the server's password changed
    sender.send(200)
    wait_until(lambda: diagnostics.count("spool_pending") == 200, 60, what="200 spooled")
    wait_until(lambda: diagnostics.level == DiagnosticStatus.ERROR
               and "Name or password is incorrect." in diagnostics.message, 60, what="ERROR with the reason")
    proxy.set(require_auth=f"robot:{secret}")               # the operator sets it back
    wait_until(lambda: diagnostics.count("stored") == 300 and diagnostics.count("spool_pending") == 0, 90,
               what="the spool drained")
    assert stored_xs(f"{couchdb_server.url}/{name}") == [float(i) for i in range(300)]
    shown = str(diagnostics.levels) + str(diagnostics.values) + launch.log_tail(400)
    assert secret not in shown
    sender.close()


@pytest.mark.ros
def test_spool_survives_an_auth_error_during_the_drain(couchdb_server, proxy, roslaunch, tmp_path,
                                                       diagnostics):
    name = _names()
    url = proxy.database_url(name)
    launch = recorder(roslaunch, url, tmp_path)
    sender = Sender(rate=500.0).connected(launch.node_name)
    sender.send(100)
    wait_until(lambda: diagnostics.count("stored") == 100, 60, what="100 stored")
    proxy.set(timeout="writes")
    sender.send(200)
    wait_until(lambda: diagnostics.count("spool_pending") == 200, 60, what="200 spooled")
    # reads work (the probe succeeds and the drain starts), every write is refused: rotated password
    proxy.set(auth="wrong_password", auth_scope="writes")
    wait_until(lambda: proxy.answered("auth") >= 3, 60, what="three drain attempts refused")
    assert diagnostics.count("spool_pending") == 200 and diagnostics.count("stored") == 100
    proxy.clear()
    wait_until(lambda: diagnostics.count("stored") == 300 and diagnostics.count("spool_pending") == 0, 90,
               what="the spool drained")
    assert stored_xs(f"{couchdb_server.url}/{name}") == [float(i) for i in range(300)]
    sender.close()


class SizeLimit(NamedTuple):
    """A database whose server refuses documents over 20,000 bytes, as the member (`url`) and the
    admin (`admin`) see it; `lift()` is the operator raising the limit; `refused()` counts the
    proxy's refusals (None on the real server, which refuses by itself)."""

    url: str
    admin: str
    lift: Callable[[], object]
    refused: Callable[[], Optional[int]]


@pytest.fixture(params=["pouchdb", "apache"])
def size_limit(request, tmp_path):
    """pouchdb-server behind the proxy answering 413 document_too_large as CouchDB 3 does, then a
    real Apache CouchDB node with its max_document_size set to 20,000 (restored afterwards)."""
    name = _names()
    if request.param == "apache":
        server = request.getfixturevalue("apache_couchdb")
        old = server.set_config("couchdb", "max_document_size", "20000")
        try:
            yield SizeLimit(server.database_url(name), server.admin_database_url(name),
                            lambda: server.set_config("couchdb", "max_document_size", old), lambda: None)
        finally:
            server.set_config("couchdb", "max_document_size", old)
        return
    server = request.getfixturevalue("couchdb_server")
    with FaultProxy(server.url, tmp_path) as proxy:
        proxy.set(max_document_size=20000)
        yield SizeLimit(proxy.database_url(name), f"{server.url}/{name}", proxy.clear,
                        lambda: proxy.answered("max_document_size"))


@pytest.mark.ros
def test_oversized_document_is_split_out_and_only_it_is_quarantined(size_limit, roslaunch, tmp_path,
                                                                    diagnostics):
    quarantine = tmp_path / "refused.quarantine"
    launch = recorder(roslaunch, size_limit.url, tmp_path, topics=["/odom", "/notes"],
                      batch_period=3.0, quarantine_path=str(quarantine))
    notes = rospy.Publisher("/notes", String, queue_size=100)
    wait_for_subscriber(notes, launch.node_name, 60)
    sender = Sender(rate=500.0).connected(launch.node_name)
    big = String(data="x" * 60000)                    # over the limit of 20,000 bytes
    sender.send(40)
    notes.publish(String(data="small"))
    notes.publish(big)
    sender.send(40)
    wait_until(lambda: diagnostics.count("stored") == 81 and diagnostics.count("quarantined") == 1, 60,
               what="81 stored and 1 quarantined")
    refused = size_limit.refused()
    assert refused is None or refused >= 2            # the whole batch, then the document alone
    direct = size_limit.admin
    assert stored_xs(direct) == [float(i) for i in range(80)]
    with open_store(direct) as store:
        assert [m.message().data for m in store.find_messages(topic="/notes")] == ["small"]
    refused = [e for e in read_entries(quarantine) if isinstance(e, MessageRecord)]
    assert len(refused) == 1 and refused[0].raw == serialized(big)
    assert diagnostics.count("dropped") == 0 and diagnostics.level == DiagnosticStatus.WARN
    size_limit.lift()                                 # the operator raises max_document_size
    with open_store(direct) as store:
        assert import_quarantine(quarantine, store) == (1, 0)
        assert [m.message().data for m in store.find_messages(topic="/notes")][-1] == big.data
    sender.close()
    notes.unregister()


@pytest.mark.ros
def test_writer_failure_is_reported_and_the_writer_restarted(couchdb_server, proxy, roslaunch, tmp_path,
                                                             diagnostics):
    name = _names()
    launch = recorder(roslaunch, proxy.database_url(name), tmp_path)
    sender = Sender(rate=500.0).connected(launch.node_name)
    sender.send(50)
    wait_until(lambda: diagnostics.count("stored") == 50, 60, what="50 stored")
    proxy.set(bulk_answer="[null]")                   # a 201 whose body has an unexpected shape
    sender.send(100)
    wait_until(lambda: diagnostics.count("writer_restarts") >= 1, 60, what="a writer restart")
    wait_until(lambda: diagnostics.level == DiagnosticStatus.ERROR, 90, what="ERROR on /diagnostics")
    assert any("restarted" in message for _, message in diagnostics.levels)
    proxy.clear()
    wait_until(lambda: diagnostics.count("stored") == 150 and diagnostics.count("spool_pending") == 0, 90,
               what="every message stored after the restart")
    assert stored_xs(f"{couchdb_server.url}/{name}") == [float(i) for i in range(150)]
    sender.send(50)                                   # the restarted writers keep recording
    wait_until(lambda: diagnostics.count("stored") == 200, 60, what="200 stored")
    assert diagnostics.count("dropped") == 0
    sender.close()



# -- TLS with a private CA and a client certificate (the proxy serves HTTPS) --------------------------
def _openssl(*args, cwd):
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=120)


@pytest.fixture
def private_ca(tmp_path):
    """A private CA, a server certificate for 127.0.0.1 and a client certificate (real openssl)."""
    d = tmp_path / "pki"
    d.mkdir()
    _openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem",
             "-days", "2", "-subj", "/CN=robot test CA", cwd=d)
    (d / "san.ext").write_text("subjectAltName=IP:127.0.0.1\n")
    for who, extra in (("server", ["-extfile", "san.ext"]), ("client", [])):
        _openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{who}.key", "-out", f"{who}.csr",
                 "-subj", f"/CN={who}", cwd=d)
        _openssl("x509", "-req", "-in", f"{who}.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
                 "-out", f"{who}.pem", "-days", "2", *extra, cwd=d)
    return d


def test_tls_with_a_private_ca_and_a_client_certificate(couchdb_server, private_ca, tmp_path):
    tls = {"cert": str(private_ca / "server.pem"), "key": str(private_ca / "server.key"),
           "client_ca": str(private_ca / "ca.pem")}
    with FaultProxy(couchdb_server.url, tmp_path, tls=tls) as proxy:
        url = proxy.database_url(_names())
        assert url.startswith("https://")
        with pytest.raises(StoreRefused, match="TLS"):        # the system CAs do not know this one
            open_store(url)
        with pytest.raises(StoreError):                        # the server wants a client certificate
            open_store(url, tls_ca_file=str(private_ca / "ca.pem"))
        options = {"tls_ca_file": str(private_ca / "ca.pem"), "tls_cert_file": str(private_ca / "client.pem"),
                   "tls_key_file": str(private_ca / "client.key")}
        with open_store(url, **options) as store:
            store.put_topic(TopicInfo.of_class("/chatter", String))
            assert store.insert_records(_records(20)) == 20
            assert [m.message().data for m in store.find_messages()] == [f"m{i}" for i in range(20)]


def test_a_full_spool_keeps_the_batches_in_memory_until_the_server_answers(couchdb_server, proxy,
                                                                           tmp_path):
    """~spool_max_mb reached while the server times out: nothing dropped, nothing beyond the
    limit on disk; every message stored once the server answers again."""
    name = _names()
    _admin_creates(couchdb_server, name)
    limit = 4096
    with open_store(proxy.database_url(name)) as store:
        proxy.set(timeout="writes")
        spool = BoundedSpool(tmp_path / "rec.spool", max_bytes=limit, min_free_bytes=0).open()
        recorder = Recorder(store, spool, batch_size=50, batch_period=0.05, retry_period=0.2).start()
        for i in range(600):
            assert recorder.receive("/chatter", serialized(String(data=f"m{i}")),
                                    split_time(1000 + 0.01 * i), String._type, String._md5sum,
                                    String._full_text)
        wait_until(lambda: "spool refuses writes" in recorder.fault, 120, what="the spool to be full")
        counts = recorder.counts()
        assert counts["dropped"] == 0 and counts["stored"] == 0 and counts["queued"] > 0, counts
        assert (tmp_path / "rec.spool").stat().st_size <= limit
        proxy.clear()
        counts = recorder.stop(timeout=120)
        spool.close()
        assert counts["dropped"] == 0 and counts["stored"] == 600, counts
        assert counts["spool_pending"] == 0
        got = [m.message().data for m in store.find_messages(topic="/chatter")]
    assert got == [f"m{i}" for i in range(600)]


@pytest.mark.db
def test_the_proxy_forwards_chunked_request_bodies(proxy, couchdb_server):
    """Node's HTTP client streams some bodies with Transfer-Encoding: chunked (no Content-Length);
    the proxy must forward them whole, as CouchDB would read them."""
    name = _names()
    _admin_creates(couchdb_server, name)
    docs = {"docs": [{"_id": f"chunked-{i}", "n": i} for i in range(50)]}

    def pieces():  # a generator body: requests sends it chunked
        text = json.dumps(docs).encode()
        for start in range(0, len(text), 97):
            yield text[start:start + 97]

    answer = requests.post(f"{proxy.url}/{name}/_bulk_docs", data=pieces(), timeout=60,
                           headers={"Content-Type": "application/json"})
    assert answer.status_code == 201, answer.text
    stored = requests.get(f"{couchdb_server.url}/{name}/_all_docs", params={"include_docs": "true"},
                          timeout=30).json()["rows"]
    assert sorted(row["doc"]["n"] for row in stored) == list(range(50))
