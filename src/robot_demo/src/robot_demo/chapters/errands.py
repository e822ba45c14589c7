"""Errands (errand_nav): a phrase -> the place -> the crowd-aware path at two times of day -> driven
by the learned controller among simulated people -> arrival, each step checked against the
simulator's truth.

The floor is the demo's generated building with a loop (robot_sim `layout: loop`): besides the
main hall, a west and a north corridor join the back hall, a longer way round that is quiet when
the main hall fills before classes. A second simulated robot (building_sim, driven by cmd_vel; its
people walk the halls as many as the quiet hour holds) runs in the namespace /errand_robot with its own
crowd model (learned, like the crowd map chapter's, from what a people counter counts; trained in
the background from the demo's start) and the hallway reward a simulated person's demonstrations
taught (learned in the background too). The region_search chapter's nodes answer the phrase.
"""
import sys
import threading
import time

import numpy as np

from robot_demo import waits

TITLE = "Errands: a phrase to a place, round the crowds of the hour (errand_nav + move_base action)"
NS = "/errand_robot"
SEED = 0
WED = 48.0
RUSH = WED + 10 + 50 / 60      # Wednesday 10:50, ten minutes before classes: the main hall fills
QUIET = WED + 7.0              # Wednesday 07:00: the halls are quiet
START = (5.0, 6.7, 0.0)        # the main hall, 5 m from its west end
PHRASE = "where are the stairs?"
PLACE = "stairs"
CROWD, REWARD = "errand_crowd_model", "errand_hallway_reward"
MAIN_HALL = (0.2, 5.2, 25.2, 8.2)   # robot_sim.building's main hall (checked in run)
# the teacher: a simulated person of the sampling_mpc family (0.5 m/s, accepted on 3 drives)
TEACHER = ["--family", "sampling_mpc", "--floor", f"generated:{SEED}", "--demos", "3"]


def prepare(demo) -> None:
    """At the demo's start: the loop floor's crowd model and the hallway reward are made in the
    background, one after the other, once the crowd map chapter's training (when there is one)
    is done (each skipped when the demo's output already holds it)."""
    jobs = []
    if not (demo.output / "errand_crowd_model.npz").is_file():
        jobs.append((CROWD, [
            sys.executable, "-m", "traffic_gp.sim.cli", "train", "--counted",
            "--map", f"generated-loop:{SEED}", "--views", "1200", "--scans", "5", "--weeks", "2",
            "--steps", "200", "--inducing", "150", "--quick",
            "--out", str(demo.output / "errand_crowd_model.npz")]))
    if not (demo.output / "hallway_reward.yaml").is_file():
        jobs.append((REWARD, [
            sys.executable, "-m", "lfd_controller.sim.teach_hallway", *TEACHER,
            "--out", str(demo.output / "hallway_reward.yaml")]))
    before = demo.background.get("crowd_model_training")
    ready = {name: threading.Event() for name, _ in jobs}

    def one_after_another():
        try:
            if before is not None:
                before.popen.wait()
            for name, argv in jobs:
                demo.start_background(name, argv).popen.wait()
                ready[name].set()
        finally:                                   # a failure is reported by the chapter
            for event in ready.values():
                event.set()
    demo.queued.update(ready)
    threading.Thread(target=one_after_another, name="errand_training", daemon=True).start()


def _finished(demo, name: str, what: str) -> None:
    queued = demo.queued.get(name)
    if queued is None:
        return
    waits.wait_until(queued.is_set, 900, what, interval=0.5)
    job = demo.background.get(name)
    if job is None:
        raise RuntimeError(f"{what} was never started")
    if job.popen.returncode != 0:
        raise RuntimeError(f"{what} failed:\n{job.log_tail(5)}")


def run(demo) -> None:
    import rospy

    from errand_nav.srv import GoToPlace
    from robot_sim.building import generate_building

    building = generate_building(SEED, loop=True)
    if next(a.box for a in building.halls if a.name == "main_hall") != MAIN_HALL:
        raise RuntimeError("the generated building's main hall moved")
    _finished(demo, CROWD, "the loop floor's crowd model (trained in the background)")
    _finished(demo, REWARD, "the hallway reward a simulated person taught (in the background)")
    launch = demo.launch(demo.workspace_launch("errands_sim.launch"), ns=NS,
                         frame_prefix="errand_robot/", layout="loop", seed=SEED,
                         start=f"[{START[0]}, {START[1]}, {START[2]}]", crowd_hour=QUIET,
                         reward_file=str(demo.output / "hallway_reward.yaml"),
                         with_crowd_model=True,
                         crowd_model_path=str(demo.output / "errand_crowd_model.npz"),
                         errand_params="{recommend_service: /region_recommender/recommend, "
                                       f"plan_hour_of_week: {QUIET}}}")
    waits.services(launch, [f"{NS}/errand_server/go_to_place", f"{NS}/errand_server/make_plan",
                            f"{NS}/traffic_gp/predict_density"], 180)
    go = rospy.ServiceProxy(f"{NS}/errand_server/go_to_place", GoToPlace)
    looked = go(phrase=PHRASE, dry_run=True)
    truth_xy = building.labels[PLACE]
    place = (looked.goal.pose.position.x, looked.goal.pose.position.y)
    print(f"  {PHRASE!r} -> {looked.label or '-'} at ({place[0]:.1f}, {place[1]:.1f}), "
          f"confidence {looked.confidence:.2f}: {looked.message}")
    if not looked.success or looked.label != PLACE or np.hypot(*np.subtract(place, truth_xy)) > 0.01:
        raise RuntimeError(f"the phrase should mean {PLACE} at {truth_xy}: {looked}")
    plans = _plans_at_two_times(demo, building, place)
    _drive(demo, go, plans, truth_xy)


def _plans_at_two_times(demo, building, place):
    """Plans at the rush and when quiet, through ~make_plan, checked against the truth."""
    import rospy
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.srv import GetPlan

    from errand_nav.forecast import DensityForecast
    from errand_nav.planning import CrowdPlanner
    from errand_nav.sim import truth_forecast
    from robot_sim.people import PeopleSimulator
    from robot_sim.ros_people import sim_stamp

    make_plan = rospy.ServiceProxy(f"{NS}/errand_server/make_plan", GetPlan)
    sim = PeopleSimulator.from_building(building, 0.5)
    planner = CrowdPlanner(building.grid)
    quiet = DensityForecast.quiet(building.grid)
    hall = next(area for area in building.halls if area.name == "main_hall").box
    plans = {}
    for label, hours in (("the rush, Wed 10:50", RUSH), ("quiet, Wed 07:00", QUIET)):
        start, goal = PoseStamped(), PoseStamped()
        start.header.frame_id = goal.header.frame_id = "map"
        start.header.stamp = sim_stamp(hours, 0.0)
        start.pose.position.x, start.pose.position.y = START[:2]
        goal.pose.position.x, goal.pose.position.y = place
        began = time.perf_counter()
        answer = make_plan(start=start, goal=goal, tolerance=0.0).plan
        took = time.perf_counter() - began
        points = np.array([[p.pose.position.x, p.pose.position.y] for p in answer.poses])
        if len(points) < 2:
            raise RuntimeError(f"no plan at {label}")
        truth = truth_forecast(sim, hours + np.arange(0.0, 0.5, 1 / 30))
        crowd = planner.evaluate(points, hours * 3600.0, truth)
        shortest = planner.plan(START[:2], place, hours * 3600.0, quiet)
        short = planner.evaluate(shortest.points, hours * 3600.0, truth)
        in_hall = _share_inside(points, hall)
        plans[label] = (points, crowd, short, in_hall)
        print(f"  at {label}: {crowd.length:.0f} m, {100 * in_hall:.0f}% of it in the main hall; "
              f"by the true crowd {crowd.duration:.0f} s and {crowd.people_met:.1f} people met "
              f"(shortest path: {short.length:.0f} m, {short.duration:.0f} s, "
              f"{short.people_met:.1f} met)   [plan {1000 * took:.0f} ms]")
    rush, quiet = plans["the rush, Wed 10:50"], plans["quiet, Wed 07:00"]
    if not (rush[3] < 0.5 and rush[1].people_met < rush[2].people_met):
        raise RuntimeError("at the rush the plan should keep out of the main hall and meet fewer "
                           "people than the shortest path")
    if not (quiet[3] > 0.5 and quiet[1].duration <= 1.05 * quiet[2].duration):
        raise RuntimeError("when quiet the plan should take the main hall, no slower than the "
                           "shortest path")
    print("  checked against the simulator's truth: the busy hall avoided at the rush (fewer "
          "people met), taken when quiet (no slower)")
    return plans


def _share_inside(points, box) -> float:
    """Share of the path's length inside an axis-aligned box."""
    middles = (points[1:] + points[:-1]) / 2
    lengths = np.hypot(*np.diff(points, axis=0).T)
    inside = ((middles[:, 0] >= box[0]) & (middles[:, 0] <= box[2]) & (middles[:, 1] >= box[1])
              & (middles[:, 1] <= box[3]))
    return float(lengths[inside].sum() / max(lengths.sum(), 1e-9))


def _drive(demo, go, plans, truth_xy) -> None:
    """The robot is sent by phrase at the quiet hour and drives among that hour's people (the
    rush's detour is 40 m: at the taught pace, about three minutes among the rush's people)."""
    import rospy
    from actionlib_msgs.msg import GoalStatus
    from move_base_msgs.msg import MoveBaseActionResult
    from nav_msgs.msg import Odometry
    from std_msgs.msg import String

    from robot_common.msg import People

    watch = {"track": [], "met": set(), "status": "running", "result": None}
    odom = rospy.Subscriber(f"{NS}/odom", Odometry, lambda m: watch["track"].append(
        (m.pose.pose.position.x, m.pose.pose.position.y)), queue_size=20)

    def people(msg):
        if watch["track"]:
            x, y = watch["track"][-1]
            watch["met"].update(p.name for p in msg.people
                                if np.hypot(p.position.x - x, p.position.y - y) <= 1.0)
    truth = rospy.Subscriber(f"{NS}/building_sim/people_truth", People, people, queue_size=5)
    status = rospy.Subscriber(f"{NS}/building_sim/status", String,
                              lambda m: watch.update(status=m.data), queue_size=2)
    # the goal goes through the server's own action client; its result is on the action's topic
    result = rospy.Subscriber(f"{NS}/move_base/result", MoveBaseActionResult,
                              lambda m: watch.update(result=m.status), queue_size=5)
    waits.wait_until(lambda: result.get_num_connections() > 0, 60,
                     "the move_base action's result topic")
    began = time.monotonic()
    sent = go(phrase=PHRASE, dry_run=False)
    print(f"  sent by phrase at the quiet hour: {sent.message}; the robot's people are as many as "
          f"the halls hold then")
    waits.wait_until(lambda: watch["result"] is not None, 300,
                     "the robot's arrival (move_base result)", interval=0.5)
    for subscriber in (odom, truth, status, result):
        subscriber.unregister()
    track = np.array(watch["track"])
    driven = float(np.hypot(*np.diff(track, axis=0).T).sum()) if len(track) > 1 else 0.0
    end = track[-1] if len(track) else np.array([np.nan, np.nan])
    outcome = {GoalStatus.SUCCEEDED: "SUCCEEDED", GoalStatus.ABORTED: "ABORTED",
               GoalStatus.PREEMPTED: "PREEMPTED"}.get(watch["result"].status, "?")
    print(f"  move_base result: {outcome} ({watch['result'].text}) in "
          f"{time.monotonic() - began:.0f} s, {driven:.0f} m driven, {len(watch['met'])} people "
          f"met within 1 m, simulator: {watch['status']}")
    if watch["result"].status != GoalStatus.SUCCEEDED or watch["status"] != "running" or \
            np.hypot(*(end - np.asarray(truth_xy))) > 0.6:
        raise RuntimeError("the robot should arrive at the stairs without touching anything")
    hall = _share_inside(track, MAIN_HALL) if len(track) > 1 else 0.0
    if hall < 0.5:
        raise RuntimeError(f"at the quiet hour the robot should take the main hall ({hall:.0%})")
