"""Recording what the counting check needs from a running simulated robot and people counter:
the scans with their tf poses, the simulator's true people at each scan and the counter's
PeopleCount messages (the counting test and benchmark use it; `counting_check` compares)."""
import threading
from typing import List

import numpy as np
import rospy
import tf2_ros
from sensor_msgs.msg import LaserScan

from robot_common.cells import CellGrid
from robot_common.msg import People, PeopleCount
from robot_common.ros_node import pose_2d
from traffic_gp.sim.counting_check import TrueScan

__all__ = ["CountedWatch", "CountingRecorder"]


class CountedWatch:
    """A PeopleCount message as `counting_check.check_counts` reads it."""

    def __init__(self, msg: PeopleCount, cells: CellGrid):
        self.start, self.duration = msg.header.stamp.to_sec(), msg.duration
        self.cells = cells.index_at(np.array([p.x for p in msg.cells]),
                                    np.array([p.y for p in msg.cells]))
        self.counts = np.asarray(msg.counts)
        self.robot_id, self.frame_id = msg.robot_id, msg.header.frame_id


class CountingRecorder:
    """Subscribes to `scan`, the simulator's `truth` topic and `counts` (after init_node);
    `stop()` unsubscribes. The map frame and the scans' frame are looked up in tf afterwards."""

    def __init__(self, *, scan="/scan", truth="/sensor_sim/people_truth", counts="/people_counts",
                 map_frame="map"):
        self.map_frame = map_frame
        self.buffer = tf2_ros.Buffer(cache_time=rospy.Duration(3600))
        self.listener = tf2_ros.TransformListener(self.buffer)
        self.scans: List[LaserScan] = []
        self.truth = {}
        self.counts: List[PeopleCount] = []
        self._lock = threading.Lock()
        self.subscribers = [
            rospy.Subscriber(scan, LaserScan, self._keep(self.scans.append), queue_size=100),
            rospy.Subscriber(truth, People, self._keep(
                lambda msg: self.truth.__setitem__(msg.header.stamp.to_sec(), msg)), queue_size=100),
            rospy.Subscriber(counts, PeopleCount, self._keep(self.counts.append), queue_size=100)]

    def _keep(self, store):
        def callback(msg):
            with self._lock:
                store(msg)
        return callback

    def stop(self) -> None:
        for subscriber in self.subscribers:
            subscriber.unregister()
        self.listener.unregister()

    def true_scans(self) -> List[TrueScan]:
        """The scans that have their truth and a transform to the map, as the check reads them."""
        out = []
        with self._lock:
            scans, truth = list(self.scans), dict(self.truth)
        for scan in scans:
            stamp = scan.header.stamp
            if stamp.to_sec() not in truth or not self.buffer.can_transform(
                    self.map_frame, scan.header.frame_id, stamp):
                continue
            pose = pose_2d(self.buffer.lookup_transform(self.map_frame, scan.header.frame_id,
                                                        stamp))
            people = [(p.name, p.position.x, p.position.y) for p in truth[stamp.to_sec()].people]
            out.append(TrueScan(stamp.to_sec(), pose, scan.angle_min, scan.angle_increment,
                                np.asarray(scan.ranges, dtype=float), people))
        return out

    def watches(self, cells: CellGrid, skip_first: bool = True) -> List[CountedWatch]:
        """The counter's watches (the first left out: it may have begun before recording)."""
        with self._lock:
            counts = list(self.counts)
        return [CountedWatch(msg, cells) for msg in counts[1 if skip_first else 0:]]
