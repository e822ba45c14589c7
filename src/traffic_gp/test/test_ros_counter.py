"""The people counter through roslaunch, against robot_sim's simulated robot: its laser (walls and
people), tf map -> odom -> base_link -> laser and a people tracker with 10% misses and 10% false
tracks, checked against the simulator's true people (traffic_gp.sim.counting_check)."""
import pytest

from robot_common.cells import CellGrid
from robot_sim import generate_building
from ros_harness import wait_until
from ros_harness.processes import master_graph
from traffic_gp.sim.counting_check import check_counts

pytestmark = pytest.mark.ros


def what_the_counter_had(rospy, master_uri: str) -> str:
    """The counter's own status and who publishes what it reads: the timeout's explanation."""
    from std_srvs.srv import Trigger

    try:
        status = rospy.ServiceProxy("/people_counter/status", Trigger)().message
    except Exception as err:  # noqa: BLE001 - the explanation must not hide the timeout
        status = f"no status ({err})"
    publishers, _, _ = master_graph(master_uri).getSystemState()
    read = ("/map", "/scan", "/people", "/tf", "/tf_static", "/people_counts", "/clock")
    return (f"status: {status}; /use_sim_time {rospy.get_param('/use_sim_time', 'unset')}; "
            f"publishers: {[p for p in publishers if p[0] in read]}")


def test_the_counter_counts_the_simulated_crowd_as_it_truly_was(roslaunch, rospy_node):
    from std_srvs.srv import Trigger

    from traffic_gp.sim.ros_counting_check import CountingRecorder

    recorder = CountingRecorder()
    try:
        # a busy Wednesday afternoon (peak density 1 person/m^2 in the main hall), 5 s watches
        roslaunch("robot_sim", "sim.launch", crowd=True, crowd_hour=62.0, peak_density=1.0)
        counter = roslaunch("traffic_gp", "people_counter.launch", watch=5.0, robot_id="robot_7")
        try:
            wait_until(lambda: len(recorder.counts) >= 9, 300, what="9 watches of counts",
                       check=counter.process.check_alive)
        except TimeoutError as err:
            raise AssertionError(f"{err}; {what_the_counter_had(rospy_node, counter.master_uri)}") from err
    finally:
        recorder.stop()
    status = rospy_node.ServiceProxy("/people_counter/status", Trigger)().message
    assert "robot robot_7" in status and "scans used" in status, status
    # the simulator's tracker reports on every scan, just after it: each scan waits for its own
    # people message (taking the one before counted its tracks twice and varied with the load)
    assert "scans sharing a people message 0," in status, status
    cells = CellGrid.from_map(generate_building(0).grid, 0.5)
    watches = recorder.watches(cells)
    assert {(w.robot_id, w.frame_id) for w in watches} == {("robot_7", "map")}
    result = check_counts(cells, watches, recorder.true_scans(), max_range=8.0)
    assert result.truth >= 50, result.line()
    # the 10% target is the benchmark's (bench/traffic_gp/people_counting.py, 24 watches). These
    # 8 watches gave 0.95 quiet and 0.95-0.96 with both cores busy (two runs each; people seen in
    # fewer than min_detections scans are never counted): 15% here
    assert 0.85 <= result.count_ratio <= 1.15, result.line()
    assert result.recall >= 0.95, result.line()
    assert result.hidden_reported == 0, result.line()
