"""The whole stack from launch/demo.launch, as a user roslaunches it: every part comes up and does
its job end to end (recording into CouchDB, object clusters, region search, crowd model services,
joystick teleop of the demonstration robot)."""
import math
import re

import pytest

from ros_harness import wait_until

pytestmark = pytest.mark.ros

SERVICES = [
    "/igmm_layers/locate_objects",
    "/igmm_layers/lookup_object",
    "/region_recommender/recommend",
    "/embedding_server/similarity",
    "/traffic_gp/predict_count",
    "/traffic_gp/predict_region",
    "/lfd/demo_recorder/start",
]
TOPICS = ["/map", "/odom", "/scan", "/camera/rgb/image_raw", "/joint_states", "/lfd/odom"]


@pytest.fixture
def stack(roslaunch, couchdb_url, workspace_root, tmp_path):
    launch = roslaunch(str(workspace_root / "launch" / "demo.launch"), db_url=couchdb_url,
                       crowd_model_path=str(tmp_path / "crowd_model"))
    launch.wait_for_topics(TOPICS, timeout=90)
    launch.wait_for_services(SERVICES, timeout=180)
    return launch


def test_demo_launch_brings_up_the_whole_stack_and_each_part_works(stack, rospy_node, couchdb_url):
    import rospy
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Joy

    from igmm_layers.srv import LocateObjects
    from region_search.srv import RecommendRegion
    from ros_mongo import open_store
    from traffic_gp.srv import PredictCount

    # 1. the recorder stores the simulated robot's odometry in the database
    with open_store(couchdb_url) as store:
        wait_until(lambda: store.count_messages(topic="/odom") >= 20, timeout=60,
                   what="/odom messages stored by the recorder")
        stored = next(iter(store.find_messages(topic="/odom")))
        assert stored.message().header.frame_id == "odom"

    # 2. object layers learn clusters from the simulated detections
    locate = rospy.ServiceProxy("/igmm_layers/locate_objects", LocateObjects)

    def clusters():
        response = locate(class_name="any", region_id="", layer="objects")
        return response.clusters if response.success else []

    wait_until(lambda: len(clusters()) >= 5, timeout=90, what="object clusters learned from detections")
    for cluster in clusters():
        assert math.isfinite(cluster.mean.x) and math.isfinite(cluster.mean.y)
        assert cluster.observations >= 1 and cluster.weight > 0

    # 3. region search ranks the places the regions layer learned for a phrase
    recommend = rospy.ServiceProxy("/region_recommender/recommend", RecommendRegion)

    def recommended():
        answer = recommend(phrase="somewhere to wash my hands", top_k=3)
        return answer if answer.success and len(answer.labels) == 3 else None

    answer = wait_until(recommended, timeout=120, what="three labelled places recommended")
    assert set(answer.sources) == {"regions_layer"}
    assert len(answer.labels) == 3 and list(answer.scores) == sorted(answer.scores, reverse=True)
    assert not recommend(phrase="  ", top_k=3).success

    # 4. the crowd model receives the simulated robots' people counts; until it has enough to
    #    train it says so instead of making up a number
    predict = rospy.ServiceProxy("/traffic_gp/predict_count", PredictCount)

    def messages_received():
        """PeopleCount messages received so far, or None once the model answers."""
        reply = predict(x=1.0, y=1.0, stamp=rospy.Time(0))
        if reply.success:
            assert reply.expected_count >= 0 and reply.lower <= reply.upper
            return None
        found = re.search(r"(\d+) PeopleCount messages received", reply.message)
        assert found, reply.message
        return int(found.group(1))

    first = messages_received()
    if first is not None:
        def grew() -> bool:
            now = messages_received()
            return now is None or now > first

        wait_until(grew, timeout=60, what="people-count observations arriving")

    # 5. the demonstration robot in /lfd drives when the joystick's dead-man button is held
    start = rospy_node.wait_for_message("/lfd/odom", Odometry, timeout=90).pose.pose.position
    joy = rospy.Publisher("/lfd/joy", Joy, queue_size=10)
    held = Joy(axes=[0.0, 1.0, 0, 0, 0, 0, 0, 0], buttons=[0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0])

    def moved() -> bool:
        held.header.stamp = rospy.Time.now()
        joy.publish(held)
        now = rospy_node.wait_for_message("/lfd/odom", Odometry, timeout=60).pose.pose.position
        return math.hypot(now.x - start.x, now.y - start.y) > 0.2

    wait_until(moved, timeout=90, what="the /lfd robot moving under joystick teleop")
