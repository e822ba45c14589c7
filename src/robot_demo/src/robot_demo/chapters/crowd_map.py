"""Crowd map (traffic_gp): a GP of people counts over the halls and the day, served as a cost map.

Loads the demo's crowd model, or trains a small, quick one once, in the background from the
demo's start: from what a robot's people counter counts at stops spread over two weeks of
weekdays (the counter's core, the simulated laser and a tracker with misses and false tracks:
`traffic_gp.sim.counted`); no hold-out days, so no settings chosen, no baselines compared and no
intervals calibrated, as the node's full model does. Then it starts a robot that counts the
people it senses (its laser, tf and a people tracker with misses and false tracks among simulated
people; traffic_gp's people_counter) and the crowd model server (which loads the model without
retraining and keeps learning online from the counter's counts), compares its answers with the
simulator's truth and checks the crowd cost map a costmap_2d static layer would read. The
counting robot's people are those of a fixed busy time of week (CROWD_HOUR, Wednesday 14:00),
not of the clock's: the chapter counts the same crowd whenever it runs.
"""
import sys

import numpy as np

from robot_demo import waits

TITLE = "Crowd map: when and where people are in the halls (traffic_gp)"
NODE = "/traffic_gp"
WED = 48.0
CROWD_HOUR = WED + 14.0     # the counting robot's people: Wednesday 14:00, a busy hour
SEED = 0
COUNTED_VIEWS = 1200     # robot stops the demo model's counts come from (about 30 CPU-s)


TRAINING = "crowd_model_training"


def _saved_model(demo):
    """The demo's model file when it is there and of this format version, else None."""
    from traffic_gp.errors import ModelFormatError
    from traffic_gp.persistence import read_header

    path = demo.output / "crowd_model.npz"
    try:
        return path, read_header(path)
    except ModelFormatError:
        return None


def prepare(demo) -> None:
    """At the demo's start: train the demo's model in the background when there is none (the
    chapters before this one mostly wait on ROS; the training uses the idle CPU)."""
    if _saved_model(demo) is not None:
        return
    demo.start_background(TRAINING, [
        sys.executable, "-m", "traffic_gp.sim.cli", "train", "--counted", "--map", "generated:0",
        "--views", str(COUNTED_VIEWS), "--scans", "5", "--weeks", "2", "--steps", "200",
        "--inducing", "150", "--quick", "--out", str(demo.output / "crowd_model.npz"),
        "--report", str(demo.output / "crowd")])


def model_file(demo):
    """The demo's model: loaded, or the one `prepare` is training (waited for here)."""
    saved = _saved_model(demo)
    if saved is not None:
        path, header = saved
        print(f"  model: {path} ({header['n_steps']} steps on {header['n_rows']} rows; "
              "loaded, not retrained)")
        return path
    training = demo.background.get(TRAINING)
    if training is None:                    # --only without the demo's start: train now
        prepare(demo)
        training = demo.background[TRAINING]
    print(f"  model: a small, quick demo model, learned from what a robot's people counter counts "
          f"({COUNTED_VIEWS} stops of a robot over two weeks of weekdays, its laser and a tracker "
          "with 10% misses and false tracks), trained in the background since the demo started "
          "(the node's default is the full model with its settings chosen on hold-out days)",
          flush=True)
    waits.wait_until(lambda: not training.alive, 600, "the demo model's training")
    if training.popen.returncode != 0:
        raise RuntimeError(f"training failed:\n{training.log_tail(5)}")
    shown = [line for line in training.log_tail(200).splitlines()
             if "\r" not in line and not line.startswith(("I0000", "E0000", "W0000", "WARNING"))]
    print("\n".join("    " + line for line in shown[-10:]))
    print(f"  plots in {demo.output / 'crowd'}; the training's log: {training.log_path}")
    return _saved_model(demo)[0]


def run(demo) -> None:
    import rospy
    from nav_msgs.msg import OccupancyGrid

    from robot_sim import generate_building
    from robot_sim.params import PeopleSimParams
    from robot_sim.people import PeopleSimulator
    from robot_sim.ros_people import sim_stamp
    from traffic_gp.sim.evaluation import showcase_cells
    from traffic_gp.srv import PredictCount, PredictRegion

    path = model_file(demo)
    have_map = any(name == "/map" for name, _ in rospy.get_published_topics())
    launch = demo.launch(demo.workspace_launch("crowd_sim.launch"), seed=SEED, with_map=not have_map,
                         model_path=str(path), counted=True, crowd_hour=CROWD_HOUR,
                         publish_period=2.0)
    waits.services(launch, [f"{NODE}/predict_count", f"{NODE}/predict_region"], 180)
    count = rospy.ServiceProxy(f"{NODE}/predict_count", PredictCount)
    region = rospy.ServiceProxy(f"{NODE}/predict_region", PredictRegion)
    # the truth of the simulated robots: the people simulator as people_sim.launch configures it
    config = demo.sim_config(PeopleSimParams, "people_sim.yaml")
    sim = PeopleSimulator.from_building(generate_building(SEED), config.cell_size, seed=config.sim_seed)
    cells = showcase_cells(sim)
    print("  expected people per 0.5 m cell, model (90% interval of the count) vs truth:")
    for label, hours in (("Wed 01:00", WED + 1.0), ("Wed 10:50", WED + 10 + 50 / 60)):
        for name, index in cells.items():
            answer = count(sim.cells.x[index], sim.cells.y[index], sim_stamp(hours, 0.0))
            if not answer.success:
                raise RuntimeError(answer.message)
            truth = sim.expected_count(hours, [index])[0, 0]
            print(f"    {label}  {name:14s} model {answer.expected_count:.3f} "
                  f"[{answer.lower:.0f}, {answer.upper:.0f}]  truth {truth:.3f}")
    hall = next(area for area in generate_building(SEED).halls if area.name == "main_hall")
    x0, y0, x1, y1 = hall.box
    from geometry_msgs.msg import Point32, Polygon

    polygon = Polygon([Point32(x0, y0, 0), Point32(x1, y0, 0), Point32(x1, y1, 0),
                       Point32(x0, y1, 0)])
    inside = np.nonzero((sim.cells.x >= x0) & (sim.cells.x <= x1) & (sim.cells.y >= y0)
                        & (sim.cells.y <= y1))[0]
    # 10:50 is a rush (classes start at 11:00): ten minutes a day, which few of the small model's
    # stops meet; 14:30 is an ordinary afternoon
    for label, hours in (("Wed 01:00", WED + 1.0), ("Wed 10:50", WED + 10 + 50 / 60),
                         ("Wed 14:30", WED + 14.5)):
        answer = region(polygon, sim_stamp(hours, 0.0))
        truth = sim.expected_count(hours, inside).sum()
        print(f"  whole main hall at {label}: model {answer.expected_count:.1f} people "
              f"[{answer.lower:.1f}, {answer.upper:.1f}] in {answer.cells} cells, truth {truth:.1f}")
    grid = waits.message("/map", OccupancyGrid, 60)
    crowd = waits.message(f"{NODE}/crowd_costmap", OccupancyGrid, 120)
    values, walls = np.asarray(crowd.data), np.asarray(grid.data) == 100
    print(f"  /traffic_gp/crowd_costmap: {crowd.info.width}x{crowd.info.height} at "
          f"{crowd.info.resolution:.2f} m (same as /map: "
          f"{(crowd.info.width, crowd.info.height) == (grid.info.width, grid.info.height)}), "
          f"costs {values[~walls].min()}..{values[~walls].max()} on free cells, walls "
          f"{'all -1' if np.all(values[walls] == -1) else 'NOT -1'} "
          "(max over now + 30 min, for a static layer with use_maximum)")
    def model_rows(message: str) -> int:            # "ok: model of N rows, S steps; ..."
        return int(message.split("model of ")[1].split()[0])

    first = count(10.0, 6.5, rospy.Time(0)).message
    later = waits.wait_until(lambda: (lambda m: m if model_rows(m) > model_rows(first) else None)(
        count(10.0, 6.5, rospy.Time(0)).message), 180, "the model to take in new counts")
    print(f"  online learning from the robot's people counter: '{first}' -> '{later}'")
    from std_srvs.srv import Trigger

    counter = rospy.ServiceProxy("/counting_robot/people_counter/status", Trigger)

    def counted_someone():                   # "...; people counted N, ..."
        message = counter().message
        return message if int(message.split("people counted ")[1].split(",")[0]) > 0 else None

    status = waits.wait_until(counted_someone, 120, "the counting robot to count people "
                                                    "(Wednesday 14:00's crowd)")
    print(f"  people_counter (laser + tf + tracker -> PeopleCount): {status}")
