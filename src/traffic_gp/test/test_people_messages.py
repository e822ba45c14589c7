"""The people counter reads the common people messages by their layout (no roscore needed)."""
from io import BytesIO

from geometry_msgs.msg import Point

from robot_common.msg import People, Person, PositionMeasurement, PositionMeasurementArray
from traffic_gp.ros_counter import read_people


def serialised(msg) -> bytes:
    buffer = BytesIO()
    msg.serialize(buffer)
    return buffer.getvalue()


def test_a_people_msgs_people_stream_reads_as_its_names_and_positions():
    msg = People(people=[Person(name="7", position=Point(1.5, -2.0, 0.0), reliability=0.9),
                         Person(name="", position=Point(3.0, 4.0, 0.0))])
    msg.header.frame_id = "odom"
    for kind in ("people_msgs/People", "robot_common/People"):
        header, people = read_people(kind, serialised(msg))
        assert header.frame_id == "odom"
        assert people == [("7", 1.5, -2.0), ("", 3.0, 4.0)]


def test_a_leg_detector_stream_reads_as_its_object_ids_and_positions():
    measured = PositionMeasurement(name="leg_detector", object_id="Person12",
                                   pos=Point(0.5, 0.25, 0.0), covariance=[0.0] * 9)
    msg = PositionMeasurementArray(people=[measured], cooccurrence=[])
    msg.header.frame_id = "laser"
    header, people = read_people("people_msgs/PositionMeasurementArray", serialised(msg))
    assert header.frame_id == "laser" and people == [("Person12", 0.5, 0.25)]


def test_another_message_type_is_not_read():
    assert read_people("spencer_tracking_msgs/TrackedPersons", b"") is None
