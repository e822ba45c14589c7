"""The ROS nodes through roslaunch: observations in, services and crowd cost maps out."""
import math
import re
from pathlib import Path

import numpy as np
import pytest

from robot_common.maps import OCCUPIED, save_map
from robot_common.msg import PeopleCount
from robot_sim import generate_building
from robot_sim.people import PeopleSimulator
from robot_sim.ros_people import sim_stamp
from ros_harness import wait_for_subscriber, wait_until
from traffic_gp.model import TrafficGP
from traffic_gp.observations import Observations
from traffic_gp.persistence import read_header
from traffic_gp.srv import PredictCount, PredictDensity, PredictRegion

pytestmark = pytest.mark.ros
NODE = "/traffic_gp"
# The workspace-level composition of robot_sim's map and people simulators with this server.
CROWD_SIM = Path(__file__).resolve().parents[3] / "launch" / "crowd_sim.launch"


def services(rospy):
    return (rospy.ServiceProxy(f"{NODE}/predict_count", PredictCount),
            rospy.ServiceProxy(f"{NODE}/predict_region", PredictRegion))


def rows_received(message: str) -> int:
    return int(message.split(";")[1].split()[0])


def steps_trained(message: str) -> int:
    """The model's training steps in a status message ("... model of N rows, S steps; ...")."""
    found = re.search(r"rows, (\d+) steps", message)
    assert found, message
    return int(found.group(1))


def test_learns_from_simulated_robots_and_serves_a_crowd_costmap(roslaunch, rospy_node, tmp_path):
    import rospy
    from geometry_msgs.msg import Point, Point32
    from nav_msgs.msg import OccupancyGrid
    from std_srvs.srv import Trigger

    model_path = tmp_path / "crowd.npz"
    # the baselines are served at once; the GP's first fit runs in the background (the
    # hold-out, the baselines' comparison, the calibration), a small GP with its settings given
    # and short online rounds: the choice of settings and what each gives are the model tests'
    # subject (test_selection), serving while the GP is chosen is the next test's; 3 views a
    # second (about 300 rows): the rows do not grow the 8 times that start a second choice of
    # settings while the first fit runs (and none is started: on a busy machine the first fit
    # can take long enough for the rows to grow that much)
    launch = roslaunch(str(CROWD_SIM), seed=0, time_scale=600, rate=3,
                       min_rows=1500, initial_steps=10, refit_growth=0, reselect_growth=0,
                       publish_period=1.0,
                       model_path=str(model_path), n_inducing=30,
                       model="{likelihood: poisson, profile: none, spatial_inputs: xy, "
                             "hourly: false, online_steps: 5, refit_steps: 5, eval_every: 5}")
    launch.wait_for_services([f"{NODE}/predict_count", f"{NODE}/predict_region"], timeout=90)
    count, region = services(rospy)
    answer = wait_until(lambda: count(10.0, 6.5, rospy.Time(0)).success, 300,
                        what="a first forecast from the simulated robots")
    first = count(10.0, 6.5, rospy.Time(0))
    assert answer and first.expected_count >= 0 and first.lower <= first.upper
    assert first.cell_size == pytest.approx(0.5) and rows_received(first.message) >= 1500
    status = rospy.ServiceProxy(f"{NODE}/status", Trigger)

    def gp_served():
        text = status().message
        return text if "learner: serving the GP" in text else None

    # the GP's first fit imports TensorFlow and compiles its steps: on a busy 2-core machine that
    # alone can take minutes; the baselines answer meanwhile
    text = wait_until(gp_served, 600, what="the GP to replace the baselines")
    assert "model: model of" in text and "serving" in text, text
    assert "held-out" in text or "no time-ordered hold-out" in text, text

    grid = rospy.wait_for_message("/map", OccupancyGrid, 30)
    crowd = rospy.wait_for_message(f"{NODE}/crowd_costmap", OccupancyGrid, 30)
    assert (crowd.info.width, crowd.info.height) == (grid.info.width, grid.info.height)
    assert crowd.info.resolution == pytest.approx(grid.info.resolution)
    assert crowd.header.frame_id == "map"
    walls = np.asarray(grid.data) == OCCUPIED
    values = np.asarray(crowd.data)
    assert np.all(values[walls] == -1)
    assert np.all((values[~walls] >= 0) & (values[~walls] <= 95))
    assert values[~walls].max() > 0

    whole = region(None, rospy.Time(0))
    assert whole.success and whole.cells > 100
    assert whole.area == pytest.approx(whole.cells * 0.25, rel=1e-6)
    assert whole.lower <= whole.expected_count <= whole.upper

    # bad requests: clear answers, the node keeps working
    wall = count(0.05, 0.05, rospy.Time(0))
    assert not wall.success and "not in a free cell" in wall.message
    assert not count(math.nan, 1.0, rospy.Time(0)).success
    from geometry_msgs.msg import Polygon
    two = region(Polygon([Point32(1, 1, 0), Point32(2, 2, 0)]), rospy.Time(0))
    assert not two.success and "3 vertices" in two.message
    bad = PeopleCount(robot_id="broken", cells=[Point(10.0, 6.5, 0)], seen_fraction=[1.0, 1.0],
                      counts=[1])
    publisher = rospy.Publisher("/people_counts", PeopleCount, queue_size=1)
    wait_for_subscriber(publisher, NODE, 90)
    publisher.publish(bad)
    wait_until(lambda: "dropped a PeopleCount from 'broken'" in launch.log_tail(400), 300,
               what="the malformed message to be reported")
    later = wait_until(lambda: count(10.0, 6.5, rospy.Time(0)), 90, what="an answer")
    assert later.success and rows_received(later.message) > rows_received(first.message)

    saved = rospy.ServiceProxy(f"{NODE}/save_model", Trigger)()
    assert saved.success and model_path.exists()
    assert read_header(model_path)["n_rows"] > 0


SAVED_STEPS = 5  # the saved model's training steps (each about 0.2 CPU-s in this process)


@pytest.fixture
def saved_model(tmp_path):
    """A tiny model trained here on simulated counts, and the building's map file."""
    building = generate_building(0)
    sim = PeopleSimulator.from_building(building, 0.5, seed=2)
    obs = Observations.from_views(sim.cells, sim.observe(60, start=48.0, hours=24.0))
    # SAVED_STEPS: how good the model is does not matter (the node's answers are compared with
    # GPflow's predictions of this same model), only that it was trained; online_steps=5 (saved
    # with the model): the node's training after loading is a few eager steps, enough to show
    # that it continues from the file's state (more than SAVED_STEPS)
    model = TrafficGP(n_inducing=30, n_steps=SAVED_STEPS, batch_size=256, likelihood="negbin",
                      profile="none", refit_steps=0, online_steps=5).fit(obs)
    return model, model.save(tmp_path / "model.npz"), save_map(building.grid, tmp_path / "map.yaml")


def check_density_grids(rospy, model, hours, map_yaml):
    """`~predict_density` at `hours`: the model's 0.5 m cell grid over the map, GPflow's
    prediction at the centre of the cell holding (10.1, 6.6) the reference; too many stamps
    refused."""
    from robot_common.maps import load_map

    grids = rospy.ServiceProxy(f"{NODE}/predict_density", PredictDensity)
    answer = grids([sim_stamp(h, 0.0) for h in hours])
    assert answer.success, answer.message
    info, fine = answer.info, load_map(map_yaml)
    assert info.resolution == pytest.approx(0.5)
    assert (info.width, info.height) == (fine.width // 5, fine.height // 5)
    density = np.asarray(answer.density).reshape(len(hours), info.height, info.width)
    stddev = np.asarray(answer.stddev).reshape(density.shape)
    col = int((10.1 - info.origin.position.x) // info.resolution)
    row = int((6.6 - info.origin.position.y) // info.resolution)
    for k, h in enumerate(hours):
        assert density[k, row, col] == pytest.approx(model.predict(10.25, 6.75, h)[0], rel=1e-5)
        assert stddev[k, row, col] == pytest.approx(model.predict_std(10.25, 6.75, h)[0],
                                                    rel=1e-5)
    # a model cell holding any wall map cell is outside the model: density 0
    walls = fine.cells[:info.height * 5, :info.width * 5].reshape(
        info.height, 5, info.width, 5).max(axis=(1, 3)) == OCCUPIED
    assert walls.any() and np.all(density[:, walls] == 0)
    refused = grids([rospy.Time(0)] * 49)
    assert not refused.success and "49 times asked" in refused.message


def test_a_saved_model_is_served_as_saved_without_training(roslaunch, rospy_node, saved_model):
    import rospy

    model, model_path, map_yaml = saved_model
    launch = roslaunch("traffic_gp", "traffic_gp.launch", map_yaml=str(map_yaml),
                       model_path=str(model_path), utc_offset_hours=0)
    launch.wait_for_services([f"{NODE}/predict_count"], timeout=90)
    count, _ = services(rospy)
    hours = 48 + 10 + 50 / 60.0
    answer = wait_until(lambda: count(10.1, 6.6, sim_stamp(hours, 0.0)), 60, what="an answer")
    assert answer.success and steps_trained(answer.message) == SAVED_STEPS, answer.message
    # the cell holding (10.1, 6.6) has its centre at (10.25, 6.75); the node serves the saved
    # posterior in NumPy (no TensorFlow until it trains), GPflow's prediction is the reference
    expected = model.predict(10.25, 6.75, hours, 0.25)[0]
    assert answer.expected_count == pytest.approx(expected, rel=1e-6)
    check_density_grids(rospy, model, [hours, hours + 2.0], map_yaml)

    # new observations: the node loads the trainable model and keeps learning from the file's state
    from geometry_msgs.msg import Point

    publisher = rospy.Publisher("/people_counts", PeopleCount, queue_size=10)
    wait_for_subscriber(publisher, NODE, 90)
    seen = PeopleCount(robot_id="r1", cells=[Point(10.1, 6.6, 0), Point(10.6, 6.6, 0)],
                       seen_fraction=[1.0, 1.0], counts=[2, 0])
    seen.header.stamp = sim_stamp(hours, 0.0)
    publisher.publish(seen)

    def training_failed():
        assert "training failed" not in launch.log_tail(400), launch.log_tail(400)

    # the first training after loading imports TensorFlow and compiles the training step: on a
    # busy 2-core machine that alone can take minutes
    def trained_further():
        message = count(10.1, 6.6, sim_stamp(hours, 0.0)).message
        return message if steps_trained(message) > SAVED_STEPS else None

    learned = wait_until(trained_further, 600, what="online training after loading",
                         check=training_failed)
    assert f"model of {len(model.data_) + 2} rows" in learned, learned


def test_a_forecast_at_once_and_new_robots_served_while_the_gp_is_selected(roslaunch, rospy_node,
                                                                          tmp_path):
    """The full model (the node's defaults: settings chosen on the data, 400 inducing points)
    takes minutes to choose and fit; the tuned baselines answer from the first rows on, and a
    robot that starts counting while the GP is being chosen is served before it is done."""
    import rospy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from geometry_msgs.msg import Point
    from std_srvs.srv import Trigger

    building = generate_building(0)
    map_yaml = save_map(building.grid, tmp_path / "map.yaml")
    # publish_period 1 s: /diagnostics (and the cost maps) each second, not every 5 s; the GP's
    # choice runs in the background until the node stops, so a shorter wait costs less CPU
    launch = roslaunch("traffic_gp", "traffic_gp.launch", map_yaml=str(map_yaml), min_rows=600,
                       utc_offset_hours=0, clock="observations", publish_period=1.0)
    launch.wait_for_services([f"{NODE}/predict_count", f"{NODE}/status"], timeout=90)
    count, _ = services(rospy)
    status = rospy.ServiceProxy(f"{NODE}/status", Trigger)
    publisher = rospy.Publisher("/people_counts", PeopleCount, queue_size=100)
    diagnostics = []
    rospy.Subscriber("/diagnostics", DiagnosticArray, diagnostics.append)
    wait_for_subscriber(publisher, NODE, 90)
    sim = PeopleSimulator.from_building(building, 0.5, seed=3)
    free = np.arange(sim.cells.n_cells)
    seen, unseen = free[: free.size // 2], free[free.size // 2:]

    def message(robot, cells, hours, counts):
        msg = PeopleCount(robot_id=robot, cells=[Point(sim.cells.x[i], sim.cells.y[i], 0)
                                                 for i in cells],
                          seen_fraction=[1.0] * len(cells), counts=list(counts))
        msg.header.stamp = sim_stamp(hours, 0.0)
        return msg

    rng = np.random.default_rng(0)
    for hour in range(8, 20):        # r1: 12 hours of one Tuesday, 100 cells each
        cells = rng.choice(seen, 100, replace=False)
        publisher.publish(message("r1", cells, 24 + hour + 0.25, rng.poisson(0.5, 100)))
    first = wait_until(lambda: (lambda a: a if "model of 1200 rows" in a.message else None)(
        count(sim.cells.x[seen[0]], sim.cells.y[seen[0]], sim_stamp(24 + 12.25, 0.0))), 120,
        what="a first forecast of r1's 1200 rows (the baselines, at once)")
    assert first.success and first.lower <= first.expected_count <= first.upper + 1, first
    text = status().message
    assert "r1: 1200 rows from 12 messages" in text, text
    assert "serving the baselines while the GP is selected and fitted" in text, text
    item = wait_until(lambda: next((s for array in list(diagnostics) for s in array.status
                                    if s.name == "traffic_gp: crowd model"
                                    and "serving the baselines" in s.message), None), 60,
                      what="/diagnostics saying the baselines are served")
    assert item.level == DiagnosticStatus.WARN, item

    new = unseen[:20]                # r2: cells nobody saw before, 3 people in each
    publisher.publish(message("r2", new, 24 + 19.25, [3] * 20))

    def served_new():
        answer = count(sim.cells.x[new[0]], sim.cells.y[new[0]], sim_stamp(24 + 19.25, 0.0))
        return answer if "model of 1220 rows" in answer.message else None

    answer = wait_until(served_new, 120, what="the new robot's rows in the served model")
    # the answer says what served it: the baselines, the GP's choice still running
    assert "serving the baselines while the GP is selected and fitted" in answer.message, answer
    assert answer.expected_count == pytest.approx(3.0, rel=0.02), answer
    assert "r2: 20 rows from 1 messages" in status().message
