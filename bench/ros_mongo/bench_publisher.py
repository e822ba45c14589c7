"""Benchmark publishers for ros_mongo: 1 kHz nav_msgs/Odometry, 30 Hz 640x480 rgb8 sensor_msgs/Image
and 40 Hz 1081-beam sensor_msgs/LaserScan at the same time, each on its own thread with an absolute
schedule.

Messages are serialized once; each one sent gets its own header.seq (the message's index) and
stamp patched into the bytes, so every message is distinct and a receiver can tell which ones it
missed. robot_sim's sensor_sim renders its data in Python and cannot hold these rates.
Prints one JSON line with the number of messages published per topic. bench/ros_mongo/
ros_mongo_bench.py runs it as a process of its own (`ros_mongo_bench.py --publish SECONDS`); by
hand, under a roscore: python bench/ros_mongo/ros_mongo_bench.py --publish 10
"""
import json
import math
import struct
import threading
import time
from io import BytesIO

import rospy
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Image, LaserScan

TOPICS = {"/odom": 1000.0, "/camera/rgb/image_raw": 30.0, "/scan": 40.0}


def samples():
    odom = Odometry()
    odom.header.frame_id, odom.child_frame_id = "odom", "base_link"
    odom.pose.pose.orientation.w = 1.0
    odom.pose.covariance = [0.01 * i for i in range(36)]
    image = Image(height=480, width=640, encoding="rgb8", step=640 * 3,
                  data=bytes((i * 31) % 251 for i in range(640 * 480 * 3)))
    image.header.frame_id = "camera_rgb_optical_frame"
    scan = LaserScan(angle_min=-2.356, angle_max=2.356, angle_increment=4.712 / 1080, range_min=0.05,
                     range_max=30.0, ranges=[2.0 + math.sin(i / 50.0) for i in range(1081)],
                     intensities=[100.0] * 1081)
    scan.header.frame_id = "laser"
    return {"/odom": odom, "/camera/rgb/image_raw": image, "/scan": scan}


def raw_class(msg):
    return type("Raw", (rospy.AnyMsg,), {"_type": msg._type, "_md5sum": msg._md5sum,
                                         "_full_text": msg._full_text, "_has_header": False,
                                         "__slots__": []})


def run_topic(topic, msg, publisher, rate, duration, start, counts):
    buffer = BytesIO()
    msg.serialize(buffer)
    template = bytearray(buffer.getvalue())
    wire = publisher.data_class()
    total = int(duration * rate)
    for index in range(total):
        due = start + index / rate
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)  # the publishing schedule itself
        now = rospy.Time.now()
        struct.pack_into("<III", template, 0, index, now.secs, now.nsecs)  # header seq, stamp
        wire._buff = bytes(template)
        publisher.publish(wire)
        counts[topic] = index + 1


def publish(duration: float, wait_subscribers: int = 1) -> int:
    """Publish the standard load for `duration` s once every topic has `wait_subscribers`
    subscribers; print the counts as one JSON line."""
    rospy.init_node("ros_mongo_bench_publisher", disable_signals=True)
    messages = samples()
    counts = {topic: 0 for topic in TOPICS}
    publishers = {t: rospy.Publisher(t, raw_class(m), queue_size=max(100, int(TOPICS[t])))
                  for t, m in messages.items()}
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and \
            min(p.get_num_connections() for p in publishers.values()) < wait_subscribers:
        time.sleep(0.05)  # polling the condition "all subscribers connected"
    start = time.monotonic() + 0.5
    threads = [threading.Thread(target=run_topic, args=(t, messages[t], publishers[t], TOPICS[t],
                                                         duration, start, counts)) for t in TOPICS]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    elapsed = time.monotonic() - start
    time.sleep(0.5)  # let the publishers' queues empty before the connections close
    print(json.dumps({"published": counts, "seconds": elapsed}), flush=True)
    rospy.signal_shutdown("done")
    return 0
