"""The simulated robot: a generated building floor and the robot's four original sensor topics."""
import threading
import time

import rospy
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Image, JointState, LaserScan

from robot_demo import waits

TITLE = "A simulated robot in a generated building (robot_sim)"
TOPICS = {"/odom": Odometry, "/scan": LaserScan, "/camera/rgb/image_raw": Image,
          "/joint_states": JointState}


def run(demo) -> None:
    sim = demo.launch("robot_sim", "sim.launch", seed=0,
                      labels_path=str(demo.output / "building_labels.json"))
    waits.topics(sim, list(TOPICS) + ["/map"], 120)
    counts = {topic: 0 for topic in TOPICS}
    lock = threading.Lock()

    def counter(topic):
        def count(_msg):
            with lock:
                counts[topic] += 1
        return count

    subscribers = [rospy.Subscriber(topic, kind, counter(topic), queue_size=50)
                   for topic, kind in TOPICS.items()]
    start = time.monotonic()
    window = 3.0
    # A rate is counted over a time window: the wait here is the measurement itself.
    time.sleep(window)
    for subscriber in subscribers:
        subscriber.unregister()
    elapsed = time.monotonic() - start
    for topic, kind in TOPICS.items():
        print(f"  {topic:24s} {kind._type:22s} {counts[topic] / elapsed:6.1f} Hz")
    if not all(counts.values()):
        raise RuntimeError(f"silent topics: {[t for t, n in counts.items() if not n]}")
    print(f"  nodes: map_publisher (pid {sim.node_pid('/map_publisher')}), "
          f"sensor_sim (pid {sim.node_pid('/sensor_sim')})")
