"""The robot's data API (ros_mongo): record the simulated robot's topics into the demo's CouchDB,
look at what was stored, query it, replay a query onto the *_mongo topics and export it to a bag."""
import threading
import time

import rospy
from diagnostic_msgs.msg import DiagnosticArray

from robot_demo.waits import wait_until
from ros_mongo import open_store, parse_query
from ros_mongo.files.bagio import export_bag

TITLE = "Recording, querying and replaying robot data (ros_mongo)"
RECORD_SECONDS = 5.0


class _Counts:
    """The recorder's counts from /diagnostics and messages arriving on replay topics."""

    def __init__(self, replay_topics):
        self.lock = threading.Lock()
        self.diagnostics = {}
        self.arrived = {t: 0 for t in replay_topics}
        self.subscribers = [rospy.Subscriber("/diagnostics", DiagnosticArray, self._diagnostics)]
        self.subscribers += [rospy.Subscriber(t, rospy.AnyMsg, self._arrive, callback_args=t)
                             for t in replay_topics]

    def _diagnostics(self, msg):
        for status in msg.status:
            if status.name == "ros_mongo_server: recorder":
                self.diagnostics = {kv.key: kv.value for kv in status.values}

    def _arrive(self, _msg, topic):
        with self.lock:
            self.arrived[topic] += 1

    def stored(self):
        return int(self.diagnostics.get("stored", 0))

    def close(self):
        for subscriber in self.subscribers:
            subscriber.unregister()


def run(demo) -> None:
    session = time.strftime("demo-%Y%m%dT%H%M%S")
    topics = ["/odom", "/scan", "/camera/rgb/image_raw", "/joint_states"]
    counts = _Counts([t + "_mongo" for t in topics])
    try:
        _record(demo, session, counts)
        with open_store(demo.db_url) as store:
            stored = _show(store, session)
            _replay(demo, session, counts, stored)
            bag = demo.output / f"{session}.bag"
            result = export_bag(store, parse_query(f"session_id {session}"), bag, progress=False)
            print(f"  exported the session to {bag.name}: {result.messages} messages, "
                  f"{result.bytes / 1e6:.1f} MB (ros_mongo_bag export)")
    finally:
        counts.close()


def _record(demo, session, counts) -> None:
    recorder = demo.launch("ros_mongo", "ros_mongo_server.launch", db_url=demo.db_url, session_id=session,
                           robot_id="sim_robot", include="[^/map$]",
                           spool_path=str(demo.output / "ros_mongo_server.spool"))
    wait_until(lambda: counts.stored() > 0, 60, what="the recorder's first stored messages",
               check=recorder.process.check_alive)
    print(f"  ros_mongo_server recording into {demo.db_url} (session {session}) ...")
    time.sleep(RECORD_SECONDS)  # the recording window itself
    recorder.stop()
    values = counts.diagnostics
    print(f"  recorder: received {values.get('received')}, stored {values.get('stored')}, "
          f"dropped {values.get('dropped')} (last /diagnostics before shutdown; shutdown flushes the rest)")


def _show(store, session):
    stored = {}
    print(f"  {'topic':26s} {'type':26s} {'messages':>8s} {'bytes/msg':>10s}  kept as")
    for info in store.topics():
        messages = list(store.find_messages(topic=info.topic, session_id=session))
        if not messages:
            continue
        stored[info.topic] = len(messages)
        size = sum(m.size for m in messages) / len(messages)
        where = "attachment" if size > store.blob_threshold else "inline bytes"
        latched = ", latched" if info.latching else ""
        print(f"  {info.topic:26s} {info.msg_type:26s} {len(messages):8d} {size:10.0f}  {where}{latched}")
    odom = next(store.find_messages(topic="/odom", session_id=session, newest_first=True, limit=1))
    pose = odom.fields["pose"]["pose"]
    print(f"  a stored /odom document's queryable fields: "
          f"header.frame_id={odom.fields['header']['frame_id']!r}, "
          f"child_frame_id={odom.fields['child_frame_id']!r}, position=({pose['position']['x']:.2f}, "
          f"{pose['position']['y']:.2f}), orientation z/w=({pose['orientation']['z']:.3f}, "
          f"{pose['orientation']['w']:.3f}), tags={odom.tags}")
    image = next(store.find_messages(topic="/camera/rgb/image_raw", session_id=session, limit=1))
    print(f"  an image keeps encoding={image.fields['encoding']!r}, step={image.fields['step']}, "
          f"{image.fields['width']}x{image.fields['height']}, frame {image.fields['header']['frame_id']!r}; "
          f"bytes identical after decoding: {_reserialized(image) == image.raw}")
    x = pose["position"]["x"]
    near = store.count_messages(topic="/odom", session_id=session,
                                fields={"pose.pose.position.x": [x - 0.25, x + 0.25]})
    print(f"  query: /odom with pose.pose.position.x in [{x - 0.25:.2f}, {x + 0.25:.2f}] -> {near} messages; "
          f"tags lidar -> {store.count_messages(tags=['lidar'], session_id=session)} scans")
    return stored


def _reserialized(stored) -> bytes:
    from io import BytesIO

    buffer = BytesIO()
    stored.message().serialize(buffer)
    return buffer.getvalue()


def _replay(demo, session, counts, stored) -> None:
    query = f"{{session_id: {session}, topics: [/odom, /scan, /camera/rgb/image_raw, /joint_states]}}"
    expected = {t + "_mongo": n for t, n in stored.items() if t + "_mongo" in counts.arrived}
    started = time.monotonic()
    demo.launch("ros_mongo", "ros_mongo_retrieve.launch", db_url=demo.db_url, query=query, rate=2.0)
    wait_until(lambda: all(counts.arrived[t] >= n for t, n in expected.items()), 120,
               what="the replayed messages")
    print(f"  ros_mongo_retriever replayed the session at rate 2.0 in {time.monotonic() - started:.1f} s "
          f"(incl. start-up): " + ", ".join(f"{t} {counts.arrived[t]}/{n}" for t, n in expected.items()))
