"""Upload rules of a fleet robot: the rules file (first match wins, a default, clear errors quoting
the bad value), the conditions (dock state, daily windows), and the recorder core holding deferred
topics on the robot's disk until the condition holds, through a recorder restart, on a real
CouchDB-API server (pouchdb-server and the real Apache CouchDB)."""
import datetime
import time

import genpy
import pytest
import requests
from nav_msgs.msg import Odometry
from ros_mongo_samples import serialized
from sensor_msgs.msg import Image

from robot_common.errors import ConfigError
from ros_harness import free_port, wait_until
from ros_mongo import StoreUnavailable, make_record, open_store
from ros_mongo.params import RecorderParams
from ros_mongo.recording.bandwidth import Bandwidth
from ros_mongo.recording.bounded_spool import BoundedSpool
from ros_mongo.recording.chunker import ChunkPolicy
from ros_mongo.recording.deferral import Deferral
from ros_mongo.recording.events import EventRing
from ros_mongo.recording.ledger import Ledger, format_ledger, read_ledger
from ros_mongo.recording.recorder import Recorder
from ros_mongo.recording.upload_rules import (
    DailyWindow,
    docked_from_battery,
    load_upload_rules,
    parse_upload_rules,
)

LONG = 120.0
CAMERA = "/camera/rgb/image_raw"
RULES = {"rules": [{"topics": "^/odom$", "upload": "live"},
                   {"name": "camera", "topics": ["^/camera/", "^/depth"], "upload": "when",
                    "when": {"docked": "/docked"}},
                   {"topics": "^/debug/", "upload": "local"},
                   {"topics": "^/debug/odom", "upload": "live"}],  # never reached: rule 3 first
         "default": "live"}


def at(clock):
    hours, minutes = map(int, clock.split(":"))
    return datetime.time(hours, minutes)


def test_the_first_matching_rule_wins_and_unmatched_topics_get_the_default():
    rules = parse_upload_rules(RULES)
    assert [rules.mode(t) for t in ("/odom", CAMERA, "/depth/points", "/debug/odom", "/scan")] == \
        ["live", "when", "when", "local", "live"]
    assert rules.rule_for(CAMERA).name == "camera" and rules.rule_for("/odom").name == "rule1"
    assert rules.dock_topics == ["/docked"]
    assert parse_upload_rules({"rules": [], "default": "local"}).mode("/anything") == "local"


def test_daily_windows_include_their_start_exclude_their_end_and_wrap_midnight():
    night, day = DailyWindow("22:00-06:00"), DailyWindow("09:30 - 17:00")
    assert [night.contains(at(t)) for t in ("22:00", "23:59", "00:00", "05:59", "06:00", "12:00")] == \
        [True, True, True, True, False, False]
    assert [day.contains(at(t)) for t in ("09:29", "09:30", "16:59", "17:00")] == [False, True, True, False]
    assert DailyWindow("00:00-00:00").contains(at("13:13"))  # equal ends: the whole day


def test_docked_means_a_true_bool_or_a_battery_charging_or_full():
    # BatteryState: 0 unknown, 1 charging, 2 discharging, 3 not charging, 4 full
    assert [docked_from_battery(s) for s in range(5)] == [False, True, False, False, True]
    condition = parse_upload_rules({"rules": [{"topics": "x", "upload": "when",
                                               "when": {"docked": "/dock", "window": "22:00-06:00"}}]}
                                   ).rules[0].condition
    assert not condition.holds({}, at("23:00"))                  # dock state unknown: not docked
    assert not condition.holds({"/dock": True}, at("12:00"))     # docked, outside the window
    assert condition.holds({"/dock": True}, at("23:00"))


@pytest.mark.parametrize("rules, match", [
    ({"rules": [{"topics": "^/cam(", "upload": "live"}]}, r"rule 1: bad regular expression '\^/cam\('"),
    ({"rules": [{"topics": "^/cam", "upload": "sometimes"}]}, r"rule 1: unknown upload mode 'sometimes'"),
    ({"rules": [{"topics": "^/a", "upload": "live"}, {"upload": "live"}]}, r"rule 2: 'topics' must be"),
    ({"rules": [{"topics": "^/a", "upload": "when"}]}, r"rule 1: upload: when needs 'when'"),
    ({"rules": [{"topics": "a", "upload": "when", "when": {"window": "25:00-06:00"}}]},
     r"bad window '25:00-06:00': '25:00' is not a time"),
    ({"rules": [{"topics": "a", "upload": "when", "when": {"window": "22:00"}}]},
     r"bad window '22:00': expected 'HH:MM-HH:MM'"),
    ({"rules": [{"topics": "a", "upload": "when", "when": {"docked": "dock"}}]},
     r"'docked' must be a topic name starting with '/', got 'dock'"),
    ({"rules": [{"topics": "a", "upload": "when", "when": {"charging": "/b"}}]},
     r"unknown conditions \['charging'\]"),
    ({"rules": [{"topics": "a", "upload": "when", "when": {"docked": "/d"}, "max_mb": -1}]},
     r"'max_mb' must be a positive number, got -1"),
    ({"rules": [{"topics": "a", "upload": "live", "max_mb": 5}]}, r"belong to upload: when / on_event rules"),
    ({"rules": [{"topics": "a", "upload": "on_event"}]}, r"on_event needs 'event' with before and after"),
    ({"rules": [{"topics": "a", "upload": "on_event", "event": {"before": 0, "after": 1}}]},
     r"event 'before' must be a number of seconds \(before > 0, after >= 0\), got 0"),
    ({"rules": [{"topics": "a", "upload": "when", "when": {"docked": "/d"}, "event": {}}]},
     r"'event' belongs to upload: on_event rules"),
    ({"rules": [{"topics": "a", "upload": "live", "priority": 1}]}, r"unknown keys \['priority'\]"),
    ({"rules": [{"name": "x", "topics": "a", "upload": "live"},
                {"name": "x", "topics": "b", "upload": "local"}]}, r"repeated: \['x'\]"),
    ({"rules": [], "default": "when"}, r"default must be live or local, got 'when'"),
    ({"topics": "a"}, r"expected a mapping with 'rules'"),
])
def test_a_bad_rules_document_is_a_clear_error_quoting_the_bad_value(rules, match):
    with pytest.raises(ConfigError, match=match):
        parse_upload_rules(rules)


def test_a_bad_rules_file_stops_the_recorder_before_it_records(tmp_path):
    bad = tmp_path / "rules.yaml"
    bad.write_text("rules: [{topics: '^/odom', upload: live}\n")  # unclosed
    with pytest.raises(ConfigError, match=r"rules.yaml is not valid YAML"):
        load_upload_rules(bad)
    with pytest.raises(ConfigError, match=r"cannot read the upload rules file .*missing.yaml"):
        RecorderParams.from_mapping({"upload_rules": str(tmp_path / "missing.yaml")})
    bad.write_text("rules:\n  - {topics: '[', upload: live}\n")
    with pytest.raises(ConfigError, match=r"rules.yaml: upload rules: rule 1: bad regular expression"):
        RecorderParams.from_mapping({"upload_rules": str(bad)})


def test_the_ledger_adds_each_run_to_the_last_and_survives_restarts(tmp_path):
    ledger = Ledger(tmp_path / "s.ledger").load()
    first = ledger.combine({"recorded": {"/odom": 10, CAMERA: 3}, "uploaded": {"/odom": 10}},
                           {CAMERA: 3}, {})
    ledger.save(first)
    again = Ledger(tmp_path / "s.ledger").load()
    second = again.combine({"recorded": {CAMERA: 2}, "uploaded": {CAMERA: 4}, "dropped": {CAMERA: 1}},
                           {}, {CAMERA: "spool full"})
    assert second == {"/odom": {"recorded": 10, "uploaded": 10, "dropped": 0, "recycled": 0, "waiting": 0},
                      CAMERA: {"recorded": 5, "uploaded": 4, "dropped": 1, "recycled": 0, "waiting": 0,
                               "reason": "spool full"}}
    again.save(second)
    assert read_ledger(tmp_path / "s.ledger") == second
    assert "spool full" in format_ledger(second).splitlines()[1]  # the camera row (sorted first)


class Robot:
    """The recorder core with the camera deferred until docked, its spools in `work`."""

    def __init__(self, store, work, rules, bandwidth=None, now=time.time, chunks=None):
        self.spool = BoundedSpool(work / "r.spool", max_bytes=64 << 20, min_free_bytes=0).open()
        self.deferral = Deferral(rules, str(work / "r.spool"), now=now).open()
        self.recorder = Recorder(store, self.spool, batch_period=0.05, retry_period=0.2,
                                 robot_id="r1", deferral=self.deferral, bandwidth=bandwidth,
                                 chunks=chunks).start()

    def send(self, topic, cls, index, stamp=None):
        msg = cls()
        msg.header.frame_id = str(index)
        if cls is Image:
            msg.height, msg.width, msg.step, msg.encoding = 10, 100, 100, "mono8"
            msg.data = bytes(1000)
        stamp = genpy.Time.from_sec(stamp) if stamp is not None else genpy.Time(1000 + index, 0)
        assert self.recorder.receive(topic, serialized(msg), stamp, cls._type, cls._md5sum,
                                     cls._full_text)

    def stop(self):
        counts = self.recorder.stop(10.0)
        self.spool.close()
        self.deferral.close()
        return counts


def frame_ids(store, topic):
    return sorted(int(m.fields["header"]["frame_id"]) for m in store.find_messages(topic=topic))


def test_deferred_topics_wait_on_the_robot_until_docked_and_arrive_once_through_a_restart(
        couchdb_url, tmp_path):
    rules = parse_upload_rules(RULES)
    with open_store(couchdb_url) as store:
        robot = Robot(store, tmp_path, rules)
        for index in range(20):
            robot.send("/odom", Odometry, index)
            if index % 2 == 0:
                robot.send(CAMERA, Image, index)
        wait_until(lambda: len(frame_ids(store, "/odom")) == 20, LONG, what="odometry live")
        assert frame_ids(store, CAMERA) == []                       # the camera waits
        assert robot.recorder.counts()["deferred_pending"] == 10
        assert robot.deferral.pending_by_topic() == {CAMERA: 10}
        assert robot.stop()["deferred"] == 10                       # kept on disk, not sent

        robot = Robot(store, tmp_path, rules)                       # a restart while undocked
        for index in range(20, 24, 2):
            robot.send(CAMERA, Image, index)
        robot.deferral.set_docked("/docked", True)                  # docking releases the camera
        wait_until(lambda: len(frame_ids(store, CAMERA)) == 12, LONG, what="every image central")
        counts = robot.stop()
        assert frame_ids(store, CAMERA) == list(range(0, 24, 2))    # each image once
        assert frame_ids(store, "/odom") == list(range(20))
        assert counts["released"] == 12 and counts["deferred_pending"] == 0 and counts["dropped"] == 0


class FakeClock:
    """Time the test controls: waiting advances it."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now

    def wait(self, seconds):
        self.now += seconds


def test_the_bandwidth_cap_lets_live_writes_run_into_debt_and_deferred_ones_wait_for_tokens():
    clock = FakeClock()
    cap = Bandwidth(1000.0, clock=clock, wait=clock.wait)   # 1000 B/s, bursts of 1000 B
    cap.take(3000)                        # live: the bucket holds 1000, so it goes at once ...
    assert clock.now == 0.0
    cap.take(10)                          # ... and the next live write waits for the 2000 B debt
    assert clock.now == pytest.approx(2.0, abs=0.01)
    cap.take(800, live=False)             # deferred: waits until 800 B are in the bucket
    assert clock.now == pytest.approx(2.81, abs=0.01)   # (10 B of debt + 800 B) / 1000 B/s
    cap.take(5000, live=False)            # larger than a burst: waits for a full burst only
    assert clock.now == pytest.approx(3.81, abs=0.01)
    with pytest.raises(StoreUnavailable, match="bandwidth cap"):
        cap.take(10, deadline=clock.now + 1.0)   # 4000 B of debt: not before the deadline
    assert not Bandwidth(0).active


def test_a_capped_recorder_uploads_within_the_cap_and_keeps_every_message(couchdb_url, tmp_path):
    rules = parse_upload_rules(RULES)
    cap = Bandwidth(200_000.0)   # 200 KB/s; the images below are 1 KB each, odometry about 0.7 KB
    with open_store(couchdb_url) as store:   # live odometry as chunks, as on a slow link
        robot = Robot(store, tmp_path, rules, bandwidth=cap, chunks=ChunkPolicy(["/odom"], period=0.25))
        robot.deferral.set_docked("/docked", True)
        started = time.monotonic()
        for index in range(300):
            robot.send("/odom", Odometry, index, stamp=1000.0 + 0.01 * index)
            robot.send(CAMERA, Image, index)
        wait_until(lambda: robot.recorder.counts()["stored"] == 600, LONG, what="600 messages central")
        elapsed = time.monotonic() - started
        counts = robot.stop()
        assert frame_ids(store, "/odom") == frame_ids(store, CAMERA) == list(range(300))
        assert counts["dropped"] == 0 and counts["released"] == 300
        assert robot.recorder.uploaded_by_topic() == {"/odom": 300, CAMERA: 300}  # messages, not chunks
        rows = requests.get(f"{couchdb_url}/_all_docs", params={"include_docs": "true"}, timeout=60).json()
        chunks = [row["doc"] for row in rows["rows"] if row["doc"].get("kind") == "chunk"]
        assert {d["topic"] for d in chunks} == {"/odom"} and sum(d["count"] for d in chunks) == 300
        # the cap takes the encoded documents, holding the messages' bytes as base64 (4/3; a chunk
        # its messages' one after another):
        # odometry >= 701 B serialized -> >= 935 B, these images >= 1042 B -> >= 1390 B; 300 of
        # each >= 697 KB through a 200 KB/s bucket that started with one burst of 200 KB:
        # (697 - 200) / 200 = 2.49 s at the least, however fast the machine
        assert cap.waited > 0.0 and elapsed >= 2.4


def ring_record(stamp):
    secs = int(stamp)
    return make_record(CAMERA, Image, serialized(Image(height=1, width=1, step=1, data=b"x")),
                       receive=genpy.Time(secs, round((stamp - secs) * 1e9)), robot_id="r1")


def test_event_windows_keep_what_two_overlapping_triggers_cover_once_and_recycle_the_rest(tmp_path):
    infos = {}
    ring = EventRing(str(tmp_path / "r.spool.event.cam"), before=2.0, after=1.0).open()
    stamps = [100.0 + 0.5 * i for i in range(21)]          # 100.0, 100.5, ... 110.0
    for stamp in stamps[:9]:                                # up to 104.0
        ring.append(ring_record(stamp), infos)
    assert ring.trigger(104.2, "bump") == pytest.approx((102.2, 105.2))
    ring.append(ring_record(104.5), infos)
    ring.close()
    ring = EventRing(str(tmp_path / "r.spool.event.cam"), before=2.0, after=1.0).open()  # restart
    assert ring.trigger(104.7, "stall") == pytest.approx((102.7, 105.7))
    for stamp in stamps[10:13]:                             # 105.0, 105.5, 106.0
        ring.append(ring_record(stamp), infos)
    kept = {}

    def collect(now):
        for number, entries in ring.collect(now):
            kept.update({e.receive_time: e.tags for e in entries if hasattr(e, "tags")})
            ring.done(number, now)

    collect(106.1)   # decided: older than 106.1 - 2 s = 104.1 (a later trigger cannot reach them)
    assert sorted(kept) == pytest.approx([102.5, 103.0, 103.5, 104.0]) and ring.recycled == {CAMERA: 5}
    for stamp in stamps[13:]:
        ring.append(ring_record(stamp), infos)
    collect(130.0)
    # kept: [102.2, 105.7] = 102.5 ... 105.5 (7 messages); 102.5 only in bump's window, 105.5
    # only in stall's; recycled: 100.0 ... 102.0 and 106.0 ... 110.0
    assert sorted(kept) == pytest.approx([102.5, 103.0, 103.5, 104.0, 104.5, 105.0, 105.5])
    assert kept[min(kept)] == ["event:bump"]
    assert kept[max(kept)] == ["event:stall"]
    assert all(tags == ["event:bump", "event:stall"] for t, tags in kept.items() if 102.7 <= t <= 105.2)
    assert ring.recycled == {CAMERA: 5 + 9} and ring.pending_records() == 0


def test_an_event_window_triggered_twice_reaches_central_once_labelled_through_a_restart(
        couchdb_url, tmp_path):
    rules = parse_upload_rules({"rules": [{"topics": "^/camera/", "upload": "on_event",
                                           "event": {"before": 2.0, "after": 1.0}}]})
    clock = FakeClock()
    with open_store(couchdb_url) as store:
        robot = Robot(store, tmp_path, rules, now=clock)
        clock.now = 1004.2
        for index in range(21):                       # images at 1000.0, 1000.5, ... 1010.0
            robot.send(CAMERA, Image, index, stamp=1000.0 + 0.5 * index)
            if index == 8:
                robot.deferral.trigger("bump")        # keeps [1002.2, 1005.2]
            if index == 9:
                clock.now = 1004.7
                robot.deferral.trigger("stall")       # keeps [1002.7, 1005.7]
        first = robot.stop()                          # a restart before the windows are decided
        clock.now = 1020.0
        robot = Robot(store, tmp_path, rules, now=clock)
        wait_until(lambda: len(frame_ids(store, CAMERA)) == 7, LONG, what="the window central")
        wait_until(lambda: robot.recorder.counts()["event_ring"] == 0, LONG, what="the ring decided")
        counts = robot.stop()
        stored = {int(m.fields["header"]["frame_id"]): m.tags for m in store.find_messages(topic=CAMERA)}
        # 1002.5 ... 1005.5 are the images 5 ... 11; 1002.5 is in bump's window only, 1005.5 in stall's
        assert sorted(stored) == list(range(5, 12))
        assert "event:bump" in stored[5] and "event:stall" not in stored[5]
        assert "event:stall" in stored[11] and "event:bump" not in stored[11]
        assert all({"event:bump", "event:stall"} <= set(stored[i]) for i in range(6, 11))
        # recycled, by one run or the other: 1000.0 ... 1002.0 and 1006.0 ... 1010.0, each once
        assert first["recycled"] + counts["recycled"] == 5 + 9 and counts["dropped"] == 0


def test_event_rings_recycle_while_central_is_unreachable(tmp_path):
    rules = parse_upload_rules({"rules": [{"topics": "^/camera/", "upload": "on_event",
                                           "event": {"before": 2.0, "after": 1.0}}]})
    clock = FakeClock()
    down = f"http://127.0.0.1:{free_port()}/nothing_listens_here"
    with open_store(down, connect=False, timeout=1.0) as store:
        robot = Robot(store, tmp_path, rules, now=clock)
        clock.now = 1000.0
        for index in range(10):                       # 1000.0 ... 1004.5, no trigger
            robot.send(CAMERA, Image, index, stamp=1000.0 + 0.5 * index)
        clock.now = 1010.0                            # all older than before: recycled
        wait_until(lambda: robot.recorder.counts()["recycled"] == 10, LONG, what="the ring recycled")
        counts = robot.stop()
        assert counts["event_ring"] == 0 and counts["stored"] == 0 and counts["dropped"] == 0


def test_a_trigger_takes_each_rules_window_by_default_clips_before_and_refuses_bad_seconds(tmp_path):
    rules = parse_upload_rules({"rules": [
        {"name": "cam", "topics": "^/camera/", "upload": "on_event", "event": {"before": 2.0, "after": 1.0}},
        {"name": "bump", "topics": "^/bump", "upload": "on_event", "event": {"before": 5.0, "after": 0.5}}]})
    deferral = Deferral(rules, str(tmp_path / "r.spool"), now=lambda: 100.0).open()
    try:
        # 0 (the service's default) and None: each rule's own window around now = 100
        assert deferral.trigger("a", 0.0, 0.0) == [("cam", 98.0, 101.0), ("bump", 95.0, 100.5)]
        # before 3 s: cam's ring holds only 2 s (clipped), bump's 5 s; after 4 s in both
        assert deferral.trigger("b", 3.0, 4.0) == [("cam", 98.0, 104.0), ("bump", 97.0, 104.0)]
        for before, after in ((-1.0, 0.0), (0.0, float("nan")), (float("inf"), 0.0)):
            with pytest.raises(ValueError, match="finite number of seconds"):
                deferral.trigger("bad", before, after)
        assert [w[2] for w in deferral.rings["cam"].windows] == ["a", "b"]  # nothing kept for "bad"
    finally:
        deferral.close()
    live_only = Deferral(parse_upload_rules({"rules": []}), str(tmp_path / "s.spool")).open()
    with pytest.raises(ValueError, match="no upload: on_event rule"):
        live_only.trigger("x")
