"""Messages shared by the ros_mongo tests (imported through the test conftest's sys.path entry)."""
import io
import math

import genpy
import genpy.dynamic
from geometry_msgs.msg import Point
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Image, JointState, LaserScan
from std_msgs.msg import Header

CUSTOM_DEFINITION = """Header header
string label
float64[] scores
geometry_msgs/Point[] corners
uint8[] mask
================================================================================
MSG: std_msgs/Header
uint32 seq
time stamp
string frame_id
================================================================================
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
"""


def serialized(msg) -> bytes:
    buffer = io.BytesIO()
    msg.serialize(buffer)
    return buffer.getvalue()


def odometry(x=1.25, frame="odom"):
    msg = Odometry()
    msg.header.stamp = genpy.Time(100, 500)
    msg.header.frame_id = frame
    msg.child_frame_id = "base_link"
    msg.pose.pose.position.x = x
    msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = 0.6, 0.8
    msg.pose.covariance = [float(i) for i in range(36)]
    msg.twist.twist.angular.z = -0.3
    return msg


def image(width=64, height=48):
    data = bytes((i * 7) % 256 for i in range(width * height * 3))
    return Image(header=_header(7, "camera_rgb_optical_frame"), height=height, width=width,
                 encoding="rgb8", is_bigendian=0, step=width * 3, data=data)


def scan():
    ranges = [1.0 + 0.01 * i for i in range(1081)]
    ranges[3], ranges[5] = math.inf, math.nan
    return LaserScan(header=_header(9, "laser"), angle_min=-2.35, angle_max=2.35,
                     angle_increment=0.0043, range_min=0.05, range_max=30.0, ranges=ranges,
                     intensities=[0.5] * 1081)


def joints():
    return JointState(header=_header(3, ""), name=["wheel_left", "wheel_right", "pan"],
                      position=[0.1, -0.2, 1.5], velocity=[1.0, 1.0, 0.0], effort=[])


def _header(secs, frame):
    return Header(seq=0, stamp=genpy.Time(secs, 123), frame_id=frame)


def custom_class():
    return genpy.dynamic.generate_dynamic("lab_msgs/Detection", CUSTOM_DEFINITION)["lab_msgs/Detection"]


def custom_message():
    cls = custom_class()
    msg = cls()
    msg.header.frame_id, msg.header.stamp = "map", genpy.Time(5, 6)
    msg.label, msg.scores = "mug", [0.9, 0.05]
    msg.corners = [Point(1, 2, 3), Point(-1, 0.5, 0)]
    msg.mask = bytes([1, 0, 1])
    return msg
