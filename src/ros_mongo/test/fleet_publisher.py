#!/usr/bin/env python3
"""Test publisher for the fleet tests (a real ROS node, one per robot's roscore).

Publishes --count nav_msgs/Odometry on /odom at --rate Hz (header.frame_id = the message's
index; rospy numbers header.seq itself) and every 10th index also a 640x480 mono8
sensor_msgs/Image on /camera/rgb/image_raw (307 KB: stored as an attachment), once --subscribers
subscribers are connected to each topic. With --hold-at K it publishes indexes 0..K-1, then waits
until the file --go-file exists, then the rest. Prints one JSON line
{"published": {topic: count}} at the end.
"""
import argparse
import json
import os
import sys
import time

import rospy
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Image


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, required=True)
    parser.add_argument("--rate", type=float, default=50.0)
    parser.add_argument("--subscribers", type=int, default=1)
    parser.add_argument("--hold-at", type=int, default=-1)
    parser.add_argument("--go-file", default="")
    args = parser.parse_args(rospy.myargv(sys.argv)[1:])
    rospy.init_node("fleet_publisher", disable_signals=True)
    odom_pub = rospy.Publisher("/odom", Odometry, queue_size=1000)
    image_pub = rospy.Publisher("/camera/rgb/image_raw", Image, queue_size=100)
    while min(odom_pub.get_num_connections(), image_pub.get_num_connections()) < args.subscribers:
        time.sleep(0.05)  # the condition: every topic has its subscribers
    time.sleep(0.5)  # connection handshakes complete on both sides
    pixels = bytes(i % 251 for i in range(640 * 480))
    published = {"/odom": 0, "/camera/rgb/image_raw": 0}
    start = time.monotonic()
    for index in range(args.count):
        if index == args.hold_at:
            while not os.path.exists(args.go_file):
                time.sleep(0.05)  # the condition: the test says go
            start = time.monotonic() - index / args.rate
        delay = start + index / args.rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        odom = Odometry()
        odom.header.stamp, odom.header.frame_id = rospy.Time.now(), str(index)
        odom.pose.pose.position.x = index * 0.01
        odom.pose.pose.orientation.w = 1.0
        odom_pub.publish(odom)
        published["/odom"] += 1
        if index % 10 == 0:
            image = Image(height=480, width=640, encoding="mono8", step=640, data=pixels)
            image.header.stamp, image.header.frame_id = odom.header.stamp, str(index)
            image_pub.publish(image)
            published["/camera/rgb/image_raw"] += 1
    time.sleep(1.0)  # let the publisher queues empty before the connections close
    print(json.dumps({"published": published}), flush=True)
    rospy.signal_shutdown("done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
