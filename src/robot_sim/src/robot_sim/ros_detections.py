"""ROS side of the detection simulator: noisy detections of a generated building's objects and
places, published once as robot_common/ObjectObservation messages."""
from typing import List, Sequence, Tuple

import numpy as np
import rospy
from geometry_msgs.msg import Point, Vector3

from robot_common.msg import ObjectObservation
from robot_common.ros_node import read_config
from robot_sim.detections import building_detections, place_sightings
from robot_sim.params import ObjectDetectionSimParams

__all__ = ["DetectionSim", "observation", "start"]

OBJECTS_TOPIC = "/igmm_layers/observations"
PLACES_TOPIC = "/igmm_layers/place_observations"


def observation(name: str, xy: Sequence[float], confidence: float, size: Tuple[float, float, float],
                frame_id: str, region_id: str) -> ObjectObservation:
    """One ObjectObservation (z = 0; stamped when it is published)."""
    msg = ObjectObservation(class_name=name, position=Point(float(xy[0]), float(xy[1]), 0.0),
                            confidence=float(confidence), size=Vector3(*size), region_id=region_id)
    msg.header.frame_id = frame_id
    return msg


class DetectionSim:
    """Publishes, once, robot_sim.detections.building_detections(config) (Poisson numbers,
    Gaussian noise, uniform clutter, random order) and place_sightings(config) of every labelled
    place (room labels, hall landmarks).

    Parameters (robot_sim.params.ObjectDetectionSimParams, defaults in
    config/object_detection_sim.yaml): ~seed (0): building seed; ~random_seed (1): detection
    noise seed; ~mean_detections (20.0), ~noise_std (0.1 m), ~clutter_fraction (0.1),
    ~extent_spread (true): detections anywhere on an object's extent; ~with_size (true): report
    object sizes; ~place_detections (5); ~rate (500.0 messages/s); ~frame_id ("map");
    ~region_id ("").
    Topics (out): /igmm_layers/observations, /igmm_layers/place_observations
    (robot_common/ObjectObservation).

    Construction draws every message (SimError for bad detection settings); `setup()` creates the
    publishers; `publish_all()` waits for subscribers on both topics, then publishes at ~rate.
    """

    def __init__(self, config: ObjectDetectionSimParams):
        self.config = config
        building, self.detections = building_detections(config)
        dets = self.detections
        no_size = (0.0, 0.0, 0.0)
        self.objects: List[ObjectObservation] = [
            observation(dets.class_names[i], dets.positions[i], dets.confidences[i],
                        (*dets.sizes[i], 0.0) if config.with_size else no_size,
                        config.frame_id, config.region_id) for i in range(len(dets))]
        self.places: List[ObjectObservation] = [
            observation(name, xy, 1.0, no_size, config.frame_id, config.region_id)
            for name, xy in place_sightings(building, config)]

    def setup(self) -> None:
        self.publishers = [rospy.Publisher(OBJECTS_TOPIC, ObjectObservation, queue_size=1000),
                           rospy.Publisher(PLACES_TOPIC, ObjectObservation, queue_size=1000)]

    def publish_all(self) -> None:
        """Every detection, then every place sighting, stamped now; returns early on shutdown."""
        rate = rospy.Rate(50)
        while not rospy.is_shutdown() and not all(pub.get_num_connections() for pub in self.publishers):
            rate.sleep()  # wait for the layer server to subscribe
        rate = rospy.Rate(self.config.rate)
        for publisher, messages in zip(self.publishers, (self.objects, self.places)):
            for msg in messages:
                if rospy.is_shutdown():
                    return
                msg.header.stamp = rospy.Time.now()
                publisher.publish(msg)
                rate.sleep()
        rospy.loginfo(f"object_detection_sim: published {len(self.objects)} object detections "
                      f"({int(np.sum(self.detections.truth < 0))} clutter) and {len(self.places)} "
                      "place sightings")
        rospy.sleep(1.0)  # let the last messages leave the outgoing queues before exiting


def start() -> None:
    """The node's start-up: read its parameters, build it, wire ROS."""
    sim = DetectionSim(read_config(ObjectDetectionSimParams))
    sim.setup()
    sim.publish_all()
    rospy.signal_shutdown("all detections published")
