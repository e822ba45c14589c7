"""What the recorder-node tests share: its /diagnostics status, a paced Odometry sender, starting
the node under roslaunch, and reading back what it stored."""
import threading
import time
import uuid

import rospy
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry

from ros_harness import wait_for_subscriber
from ros_mongo import open_store

RECORDER_STATUS = "ros_mongo_server: recorder"


class Diagnostics:
    """The recorder's latest status from /diagnostics: level, message, values, and every
    (level, message) seen."""

    def __init__(self):
        self.level, self.message, self.values, self.levels = None, "", {}, []
        self.subscriber = rospy.Subscriber("/diagnostics", DiagnosticArray, self._receive)

    def _receive(self, msg):
        for status in msg.status:
            if status.name == RECORDER_STATUS:
                self.level, self.message = status.level, status.message
                self.values = {kv.key: kv.value for kv in status.values}
                self.levels.append((status.level, status.message))

    def count(self, key):
        return int(self.values.get(key, -1))

    def close(self):
        self.subscriber.unregister()


class Sender:
    """Publishes Odometry with pose.position.x = 0, 1, 2 ... at `rate` Hz (in the caller with
    `send`, or on a thread with `start`)."""

    def __init__(self, topic="/odom", rate=200.0):
        self.publisher = rospy.Publisher(topic, Odometry, queue_size=10000)
        self.rate, self.sent, self._stop = rate, 0, threading.Event()
        self._thread = None

    def connected(self, recorder, timeout=60):
        """Wait until the node `recorder` (its resolved name) has subscribed."""
        wait_for_subscriber(self.publisher, recorder, timeout)
        return self

    def send(self, count):
        for _ in range(count):
            if self._stop.is_set():
                return
            msg = Odometry()
            msg.pose.pose.position.x = float(self.sent)
            self.publisher.publish(msg)
            self.sent += 1
            time.sleep(1.0 / self.rate)  # pacing the publisher (its rate), not synchronisation

    def start(self, count):
        self._thread = threading.Thread(target=self.send, args=(count,), daemon=True)
        self._thread.start()
        return self

    def join(self):
        self._thread.join()

    def close(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.publisher.unregister()


def start_recorder(roslaunch, url, tmp_path, **params):
    """`ros_mongo_server` recording /odom to `url` under roslaunch, with a fresh node name (the
    parameters stay on the master) and quick retries; `params` override the settings."""
    settings = {"db_url": url, "topics": ["/odom"], "spool_path": str(tmp_path / "recorder.spool"),
                "retry_period": 0.3, "db_timeout": 2.0, "session_id": "test", "diagnostics_period": 0.2}
    settings.update(params)
    name = f"recorder_{uuid.uuid4().hex[:8]}"
    launch = roslaunch.node("ros_mongo", "ros_mongo_server", name=name, params=settings)
    launch.wait_for_nodes([f"/{name}"], timeout=90)
    launch.node_name = f"/{name}"
    return launch


def stored_xs(url, topic="/odom"):
    """The pose.position.x of every stored message on `topic`, sorted."""
    with open_store(url) as store:
        return sorted(m.fields["pose"]["pose"]["position"]["x"] for m in store.find_messages(topic=topic))
