"""ROS side of the people counter: a robot's laser, tf and people tracker in, PeopleCount out.

`PeopleCounterNode` is built from a `PeopleCounterParams` (construction is pure); `setup()` wires
ROS. The counting itself is `traffic_gp.counting.PeopleCounter` (no ROS).
"""
import bisect
import math
import os
import queue
import socket
import threading
from collections import deque
from typing import Deque, List, Optional, Sequence, Tuple

import rospy
import tf2_ros
from geometry_msgs.msg import Point
from nav_msgs.msg import OccupancyGrid
from sensor_msgs.msg import LaserScan
from std_srvs.srv import Trigger, TriggerResponse

from robot_common.cells import CellGrid
from robot_common.maps import load_map
from robot_common.msg import People, PeopleCount, PositionMeasurementArray
from robot_common.ros_maps import msg_to_grid
from robot_common.ros_node import pose_2d, read_config
from traffic_gp.counting import Detection, PeopleCounter, Scan, Watch
from traffic_gp.params import PeopleCounterParams

__all__ = ["PEOPLE_TYPES", "read_people", "nearest_people", "PeopleCounterNode", "start"]

# People messages read by their layout: robot_common's mirrors have the same fields in the same
# order as people_msgs', so the same bytes. Each gives (header, [(track id, x, y)]).
PEOPLE_TYPES = {
    "robot_common/People": People, "people_msgs/People": People,
    "robot_common/PositionMeasurementArray": PositionMeasurementArray,
    "people_msgs/PositionMeasurementArray": PositionMeasurementArray,
}


def read_people(kind: str, data: bytes):
    """(header, [(track id, x, y)]) of a serialised people message of type `kind` (one of
    PEOPLE_TYPES; None for another type). A People message's ids are its people's names, a
    PositionMeasurementArray's (leg_detector) its measurements' object_id."""
    cls = PEOPLE_TYPES.get(kind)
    if cls is None:
        return None
    msg = cls().deserialize(data)
    if cls is People:
        return msg.header, [(p.name, p.position.x, p.position.y) for p in msg.people]
    return msg.header, [(p.object_id, p.pos.x, p.pos.y) for p in msg.people]


def nearest_people(messages: Sequence[Tuple[float, List[Detection]]], stamp: float,
                   timeout: float, *, final: bool = False
                   ) -> Optional[Tuple[float, List[Detection]]]:
    """The (stamp, people) of `messages` (in stamp order, as they came) nearest in time to
    `stamp`, if within `timeout` seconds of it. A tracker reports on a scan after the scan: until
    a message stamped at or after `stamp` has come the nearest is not yet known, so None unless
    `final` (no more waiting)."""
    stamps = [entry[0] for entry in messages]
    if not final and (not stamps or stamps[-1] < stamp):
        return None
    at = bisect.bisect_left(stamps, stamp)
    near = [i for i in (at - 1, at) if 0 <= i < len(stamps)]
    best = min(near, key=lambda i: abs(stamps[i] - stamp), default=None)
    if best is None or abs(stamps[best] - stamp) > timeout:
        return None
    return messages[best]


class PeopleCounterNode:
    """Counts the people a robot sees, per map cell seen, over watches of ~watch seconds.

    Parameters (private, `PeopleCounterParams`; generated config/people_counter.yaml): ~map_yaml
      ("": the `map` topic), ~cell_size (0.5 m), ~robot_id ("": the /robot_id parameter, else the
      host name), ~watch (10 s), ~max_range (8 m), ~person_radius (0.25 m), ~dwell_time (20 s),
      ~min_detections (3), ~max_gap (0.5 s), ~people_timeout (0.5 s), ~tf_timeout (0.5 s),
      ~map_frame ("map"), ~confirm_time (1 s).
    Subscribes: `scan` (sensor_msgs/LaserScan), `people` (robot_common/People or
      PositionMeasurementArray, or people_msgs/People or PositionMeasurementArray: read by their
      layout, which is the same), `map` (nav_msgs/OccupancyGrid, when map_yaml is empty); tf from
      ~map_frame to the scan's and the people's frames.
    Publishes: `people_counts` (robot_common/PeopleCount: the cells seen in a watch, their seen
      part, the people counted in each; header.stamp the watch's start).
    Services: `~status` (std_srvs/Trigger: scans used and skipped, and why; scans that shared a
      people message with the scan before (a tracker slower than the laser); watches published,
      people counted).
    A scan is used only with a people message within ~people_timeout of its stamp and a
    transform to the map: without a tracker nothing is counted (no row says "nobody there").
    The scan's people message is the one nearest its stamp, waited for (the tracker reports on a
    scan after the scan); an ended watch is published ~confirm_time seconds of scans later.
    """

    def __init__(self, config: PeopleCounterParams):
        self.config = config
        self.counter: Optional[PeopleCounter] = None
        self._scans = queue.Queue(maxsize=100)     # LaserScan messages
        self._people: Deque[Tuple[float, List[Detection]]] = deque(maxlen=200)
        self._people_lock = threading.Lock()
        self._stop = threading.Event()
        self._used_people: Optional[float] = None      # stamp of the last people message used
        self.tally = {"scans used": 0, "no people message": 0, "no transform": 0,
                      "scans sharing a people message": 0,
                      "watches published": 0, "people counted": 0, "people messages": 0,
                      "other people types": 0}
        self.robot_id = config.robot_id

    def setup(self) -> None:
        if not self.robot_id:
            self.robot_id = str(rospy.get_param("/robot_id", "")) or socket.gethostname()
        if self.config.map_yaml:
            self._set_map(load_map(os.path.expanduser(self.config.map_yaml)))
        else:
            rospy.Subscriber("map", OccupancyGrid, lambda msg: self._set_map(msg_to_grid(msg)),
                             queue_size=1)
        self.tf_buffer = tf2_ros.Buffer(cache_time=rospy.Duration(30))
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        self.publisher = rospy.Publisher("people_counts", PeopleCount, queue_size=20)
        rospy.Subscriber("people", rospy.AnyMsg, self._on_people, queue_size=50)
        rospy.Subscriber("scan", LaserScan, self._on_scan, queue_size=20)
        rospy.Service("~status", Trigger, lambda _req: TriggerResponse(True, self.status()))
        threading.Thread(target=self._work, name="people-counting", daemon=True).start()
        rospy.on_shutdown(self._stop.set)

    def _set_map(self, grid) -> None:
        c = self.config
        self.counter = c.make_counter(CellGrid.from_map(grid, c.cell_size))
        rospy.loginfo(f"people_counter: map {grid.width}x{grid.height}, counting as {self.robot_id}")

    def status(self) -> str:
        return (f"robot {self.robot_id}; map {'in' if self.counter else 'not yet'}; "
                + ", ".join(f"{key} {value}" for key, value in self.tally.items()))

    # ---- callbacks: store only --------------------------------------------------------------
    def _on_scan(self, msg: LaserScan) -> None:
        try:
            self._scans.put_nowait(msg)
        except queue.Full:
            rospy.logwarn_throttle(10, "people_counter: falling behind; a scan was dropped")

    def _on_people(self, raw) -> None:
        kind = raw._connection_header.get("type", "")
        read = read_people(kind, raw._buff)
        if read is None:
            self.tally["other people types"] += 1
            rospy.logerr_throttle(30, f"people_counter: `people` has type {kind}; expected one "
                                      f"of {', '.join(PEOPLE_TYPES)}")
            return
        header, found = read
        try:
            x, y, yaw = pose_2d(self.tf_buffer.lookup_transform(
                self.config.map_frame, header.frame_id, header.stamp,
                rospy.Duration(self.config.tf_timeout)))
        except tf2_ros.TransformException as err:
            rospy.logwarn_throttle(10, f"people_counter: people not placed in the map: {err}")
            return
        cos, sin = math.cos(yaw), math.sin(yaw)
        people = [Detection(name, x + cos * px - sin * py, y + sin * px + cos * py)
                  for name, px, py in found]
        with self._people_lock:
            self._people.append((header.stamp.to_sec(), people))
            self.tally["people messages"] += 1

    # ---- the worker ---------------------------------------------------------------------------
    def _work(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self._scans.get(timeout=0.5)
            except queue.Empty:
                continue
            if self.counter is None:
                continue
            try:
                watch = self.take(msg)
            except Exception as err:  # noqa: BLE001 - keep counting; the error is reported
                rospy.logerr_throttle(30, f"people_counter: a scan failed: "
                                          f"{type(err).__name__}: {err}")
                continue
            if watch is not None:
                self.publish(watch)

    def _people_near(self, stamp: float) -> Optional[Tuple[float, List[Detection]]]:
        """(stamp, people) of the people message nearest in time to `stamp` (`nearest_people`):
        waits up to people_timeout for the tracker's message on this scan, not taking the
        previous scan's people meanwhile."""
        deadline = rospy.get_time() + self.config.people_timeout
        while True:
            final = rospy.get_time() >= deadline or self._stop.is_set()
            with self._people_lock:
                found = nearest_people(self._people, stamp, self.config.people_timeout,
                                       final=final)
            if found is not None or final:
                return found
            rospy.sleep(0.01)

    def take(self, msg: LaserScan) -> Optional[Watch]:
        """Count one scan; the finished watch, if it ended one."""
        near = self._people_near(msg.header.stamp.to_sec())
        if near is None:
            self.tally["no people message"] += 1
            rospy.logwarn_throttle(30, "people_counter: scans without a people message near their "
                                       "stamp are not used (is the tracker running?)")
            return None
        try:
            pose = pose_2d(self.tf_buffer.lookup_transform(
                self.config.map_frame, msg.header.frame_id, msg.header.stamp,
                rospy.Duration(self.config.tf_timeout)))
        except tf2_ros.TransformException as err:
            self.tally["no transform"] += 1
            rospy.logwarn_throttle(10, f"people_counter: scan not placed in the map: {err}")
            return None
        count = len(msg.ranges)
        angles = [msg.angle_min + i * msg.angle_increment for i in range(count)]
        scan = Scan(msg.header.stamp.to_sec(), pose, angles, msg.ranges, msg.range_min,
                    msg.range_max)
        self.tally["scans used"] += 1
        if near[0] == self._used_people:    # the tracker is slower than the laser (or stopped)
            self.tally["scans sharing a people message"] += 1
        self._used_people = near[0]
        return self.counter.add(scan, near[1], seen_at=near[0])

    def publish(self, watch: Watch) -> None:
        if len(watch.cells) == 0:
            return
        cells, c = self.counter.cells, self.config
        msg = PeopleCount(robot_id=self.robot_id, duration=watch.duration, radius=c.max_range)
        msg.header.stamp = rospy.Time.from_sec(watch.start)
        msg.header.frame_id = c.map_frame
        msg.robot_position = Point(watch.x, watch.y, 0.0)
        msg.cells = [Point(cells.x[i], cells.y[i], 0.0) for i in watch.cells.tolist()]
        msg.seen_fraction = watch.fractions.tolist()
        msg.counts = watch.counts.tolist()
        self.publisher.publish(msg)
        self.tally["watches published"] += 1
        self.tally["people counted"] += int(watch.counts.sum())


def start() -> PeopleCounterNode:
    """Read the node's parameters, build the counter and wire it to ROS (after init_node)."""
    node = PeopleCounterNode(read_config(PeopleCounterParams))
    node.setup()
    return node
