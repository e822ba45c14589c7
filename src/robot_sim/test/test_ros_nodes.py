"""The simulator node executables under a real roscore: they publish, or exit with one clear line."""
import pytest

from ros_harness import ProcessDied

pytestmark = pytest.mark.ros


def test_people_sim_publishes_people_counts(roslaunch, rospy_node):
    from robot_common.msg import PeopleCount

    sim = roslaunch("robot_sim", "people_sim.launch", rate=20.0, robots=2)
    sim.wait_for_topics(["/people_counts"], timeout=60)
    msg = rospy_node.wait_for_message("/people_counts", PeopleCount, timeout=90)
    assert msg.robot_id in ("robot_0", "robot_1") and msg.header.frame_id == "map"
    assert len(msg.cells) == len(msg.counts) == len(msg.seen_fraction) > 0


def test_object_detection_sim_publishes_its_detections_then_exits(roslaunch, rospy_node):
    from robot_common.msg import ObjectObservation
    from robot_sim.detections import building_detections, place_sightings
    from robot_sim.params import ObjectDetectionSimParams

    params = {"mean_detections": 2.0, "place_detections": 1, "rate": 2000.0}
    building, detections = building_detections(ObjectDetectionSimParams(**params))
    expected = len(detections) + len(place_sightings(building, ObjectDetectionSimParams(**params)))
    received = []
    subscribers = [rospy_node.Subscriber(topic, ObjectObservation, received.append, queue_size=5000)
                   for topic in ("/igmm_layers/observations", "/igmm_layers/place_observations")]
    try:
        sim = roslaunch.node("robot_sim", "object_detection_sim", params=params)
        sim.wait_for_exit(timeout=90)
        assert "object_detection_sim-1] process has finished cleanly" in sim.log_tail(400)
        assert len(received) == expected
    finally:
        for subscriber in subscribers:
            subscriber.unregister()


def test_a_bad_scenario_ends_the_unicycle_sim_with_one_clear_line(roslaunch):
    sim = roslaunch.node("robot_sim", "unicycle_sim", params={"scenario": "no_such_scenario"})
    with pytest.raises(ProcessDied, match="ERROR: /unicycle_sim: cannot read scenario file"):
        sim.wait_for_topics(["/odom"], timeout=90)
