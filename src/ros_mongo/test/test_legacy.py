"""The original mongodb_api's face without ROS or a database: its global parameters, its query
forms, its documents. Expected values are written by hand from the original's code and README."""
import base64
import logging

import genpy
import pytest
from sensor_msgs.msg import LaserScan

from robot_common.errors import ConfigError
from ros_mongo.compat.legacy import (
    LegacyDocumentError,
    legacy_config,
    legacy_db_url,
    legacy_overrides,
    migrated_record,
    original_document,
    original_message,
)
from ros_mongo.errors import QueryError
from ros_mongo.params import RecorderParams, RetrieverParams
from ros_mongo.query import Query, parse_query
from ros_mongo.records import StoredMessage

ORIGINAL_CONFIG = {"server_ip": "localhost", "port": 27017, "data_rate": 10, "log_image": True,
                   "log_joint": True, "log_lidar": True, "log_odom": False, "log_realsense": True,
                   "author": "ServiceRobot", "session_id": 1, "bag_name": "mongodb_to_bag.bag",
                   "where_to_write": "write_bag"}


def _lookup(params):
    def get(name):
        return params[name]  # KeyError when unset, as rospy.get_param
    return get


# -- global parameters -----------------------------------------------------------------------

def test_the_original_config_configures_the_recorder_with_one_warning_per_parameter():
    warnings = []
    config = legacy_config(RecorderParams, "recorder", {}, _lookup(ORIGINAL_CONFIG), warnings.append)
    assert config.db_url == "mongodb://localhost:27017/test_database"
    assert config.topics == ["/camera/rgb/image_raw", "/joint_states", "/scan"]  # log_odom false
    assert config.author == "ServiceRobot"
    assert config.session_id == "1"
    used = ["author", "log_image", "log_joint", "log_lidar", "log_odom", "port", "server_ip", "session_id"]
    assert len(warnings) == len(used)
    for name, line in zip(used, warnings):
        assert "\n" not in line and f"'{name}'" in line and "deprecated" in line
    assert "~author" in warnings[0] and "~topics" in warnings[4] and "~db_url" in warnings[5]


def test_private_parameters_win_over_the_original_globals():
    warnings = []
    private = {"db_url": "http://127.0.0.1:5984/mine", "author": "Alice"}
    config = legacy_config(RecorderParams, "recorder", private, _lookup(ORIGINAL_CONFIG), warnings.append)
    assert config.db_url == "http://127.0.0.1:5984/mine"
    assert config.author == "Alice"
    ignored = [line for line in warnings if "ignored" in line]
    assert len(ignored) == 3  # server_ip, port (both ~db_url) and author
    assert all("~db_url" in line or "~author" in line for line in ignored)


def test_private_parameters_at_their_defaults_count_as_not_given():
    defaults = RecorderParams.defaults()  # what the launch file loads from config/*.yaml
    overrides, _ = legacy_overrides("recorder", {"author": "Bob"}, defaults, defaults)
    assert overrides == {"author": "Bob"}


def test_no_original_globals_means_no_warning_and_todays_config():
    warnings = []
    config = legacy_config(RetrieverParams, "retriever", {}, _lookup({}), warnings.append)
    assert warnings == []
    assert config == RetrieverParams()


def test_the_retriever_takes_server_ip_port_and_data_rate():
    warnings = []
    config = legacy_config(RetrieverParams, "retriever", {"query": "tags lidar"},
                           _lookup({"server_ip": "10.1.2.3", "data_rate": 25}), warnings.append)
    assert config.db_url == "mongodb://10.1.2.3:27017/test_database"
    assert config.fixed_rate == 25.0
    assert len(warnings) == 2  # server_ip and data_rate; author etc. are not the retriever's


def test_the_converter_maps_where_to_write_and_bag_name():
    overrides, warnings = legacy_overrides(
        "converter", {"where_to_write": "write_database", "bag_name": "run.bag"},
        {"direction": "", "bag": ""}, {"direction": "", "bag": ""})
    assert overrides == {"direction": "import", "bag": "run.bag"}
    assert len(warnings) == 2


def test_legacy_db_url_defaults_to_the_originals_server():
    assert legacy_db_url() == "mongodb://localhost:27017/test_database"
    assert legacy_db_url("158.130.191.70", "27018") == "mongodb://158.130.191.70:27018/test_database"


def test_retrieve_launch_refuses_to_start_without_a_query():
    with pytest.raises(ConfigError, match="no query given"):
        RetrieverParams.from_mapping({"require_query": True})
    assert RetrieverParams.from_mapping({"require_query": True, "query": "tags lidar"}).query == "tags lidar"


# -- query forms -----------------------------------------------------------------------------

@pytest.mark.parametrize("text, expected", [
    ("author ServiceRobot", Query(author="ServiceRobot")),
    ("tags lidar", Query(tags=["lidar"])),
    ("tags:lidar", Query(tags=["lidar"])),
    ("tags=lidar", Query(tags=["lidar"])),
    ("'tags' 'lidar'", Query(tags=["lidar"])),
    ("session_id 1", Query(session_id="1")),
    ("topic /scan", Query(topics=["/scan"])),
    ("start_time 1700000000.5", Query(start_time=1700000000.5)),
    ("tags: lidar", Query(tags=["lidar"])),                                  # YAML
    ('{"author": "ServiceRobot", "tags": ["odom"]}', Query(tags=["odom"], author="ServiceRobot")),
])
def test_query_forms(text, expected):
    assert parse_query(text) == expected


def test_words_after_the_first_two_are_ignored_with_a_warning(caplog):
    with caplog.at_level(logging.WARNING, logger="ros_mongo"):
        assert parse_query("author ServiceRobot and more") == Query(author="ServiceRobot")
    assert "and more" in caplog.text and "ignored" in caplog.text


@pytest.mark.parametrize("text", ["lidar", "colour red", "fields x"])
def test_original_form_errors_name_the_problem(text):
    with pytest.raises(QueryError):
        parse_query(text)


# -- documents -------------------------------------------------------------------------------

LIDAR_DOC = {"_id": "5c1a0000000000000000000a", "session_id": 1, "author": "ServiceRobot",
             "time": 1545000000.25, "tags": ["lidar"], "time_increment": 0.5, "angle_min": 0,
             "angle_max": 100, "range_min": 10, "range_max": 20, "angle_increment": 20,
             "ranges": [10, 10, 20, 20, 10]}


def test_a_lidar_document_becomes_a_laserscan_and_says_what_it_lacks():
    tag, topic, msg, reconstructed, missing = original_message(LIDAR_DOC)
    assert (tag, topic, msg._type) == ("lidar", "/scan", "sensor_msgs/LaserScan")
    assert (msg.angle_min, msg.angle_max, msg.angle_increment) == (0.0, 100.0, 20.0)
    assert list(msg.ranges) == [10.0, 10.0, 20.0, 20.0, 10.0]
    assert sorted(reconstructed) == ["angle_increment", "angle_max", "angle_min", "range_max",
                                     "range_min", "ranges", "time_increment"]
    assert sorted(missing) == ["header.frame_id", "header.stamp", "intensities", "scan_time"]


def test_an_odom_document_fills_only_what_the_original_kept():
    doc = {"_id": 7, "time": 5.0, "tags": ["odom"], "position": [1, 2, 3], "velocity": [4, 5]}
    _tag, topic, msg, reconstructed, missing = original_message(doc)
    assert topic == "/odom"
    assert (msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.position.z) == (1, 2, 3)
    assert (msg.twist.twist.linear.x, msg.twist.twist.linear.y, msg.twist.twist.angular.z) == (4, 5, 0)
    assert "twist.twist.angular.z" in missing and "twist.twist.angular.z" not in reconstructed
    assert "pose.pose.orientation" in missing


def test_the_original_retrievers_joint_state_spelling_is_understood():
    _tag, topic, msg, _, _ = original_message({"tags": ["joint_state"], "joint_names": ["a"],
                                               "position": [1.5], "velocity": [], "effort": []})
    assert (topic, list(msg.name), list(msg.position)) == ("/joint_states", ["a"], [1.5])


@pytest.mark.parametrize("doc, reason", [({"time": 1.0}, "no tags"),
                                         ({"time": 1.0, "tags": ["kinect"]}, "unknown tag"),
                                         ({"tags": ["lidar"]}, "no time")])
def test_documents_that_cannot_be_messages_are_refused_with_a_reason(doc, reason):
    with pytest.raises(LegacyDocumentError, match=reason):
        migrated_record(doc)


def test_migrated_records_keep_the_originals_metadata_and_have_stable_ids():
    tag, record, _, _ = migrated_record(LIDAR_DOC)
    again = migrated_record(dict(LIDAR_DOC))[1]
    other = migrated_record(dict(LIDAR_DOC, _id="5c1a0000000000000000000b"))[1]
    assert record.id == again.id != other.id
    assert record.id.startswith("1545000000250000000-")
    assert (record.topic, record.author, record.session_id, record.tags) == \
        ("/scan", "ServiceRobot", "1", ["lidar"])
    assert (record.receive_secs, record.receive_nsecs) == (1545000000, 250000000)
    assert record.header_stamp is None  # the original stored none
    decoded = LaserScan()
    decoded.deserialize(record.raw)
    assert list(decoded.ranges) == [10.0, 10.0, 20.0, 20.0, 10.0]


def test_a_stored_message_reads_back_in_the_originals_form():
    _tag, record, _, _ = migrated_record(LIDAR_DOC)
    stored = StoredMessage(id=record.id, topic=record.topic, msg_type=record.msg_type,
                           md5sum=record.md5sum, receive_stamp=genpy.Time(1545000000, 250000000),
                           header_stamp=None, tags=["lidar"], session_id="1", robot_id=None,
                           fields=record.fields, size=len(record.raw), raw=record.raw,
                           load_raw=lambda _id: b"", resolve=lambda t, m: LaserScan,
                           author="ServiceRobot")
    doc = original_document(stored)
    assert doc == {"session_id": "1", "author": "ServiceRobot", "time": 1545000000.25, "tags": ["lidar"],
                   "time_increment": 0.5, "angle_min": 0.0, "angle_max": 100.0, "range_min": 10.0,
                   "range_max": 20.0, "angle_increment": 20.0, "ranges": [10.0, 10.0, 20.0, 20.0, 10.0]}


def test_image_data_reads_back_as_base64():
    _tag, record, _, _ = migrated_record({"_id": 1, "time": 2.0, "tags": ["image"], "height": 1,
                                          "width": 2, "data": b"\x01\xff"})
    from sensor_msgs.msg import Image
    stored = StoredMessage(id=record.id, topic=record.topic, msg_type=record.msg_type,
                           md5sum=record.md5sum, receive_stamp=genpy.Time(2, 0), header_stamp=None,
                           tags=["image"], session_id=None, robot_id=None, fields=None,
                           size=len(record.raw), raw=record.raw, load_raw=lambda _id: b"",
                           resolve=lambda t, m: Image)
    doc = original_document(stored)
    assert (doc["height"], doc["width"], base64.b64decode(doc["data"])) == (1, 2, b"\x01\xff")
