"""learn_reward: learning from what the robot recorded - demonstrations from bags and the database
(ros_mongo), the learned reward back into the database, and the command line (`main`); the
learning itself is `learning.learn_and_save`.

The database may be a fleet's central database (every robot's replicated recordings): each
database demonstration keeps the robot that recorded it (`demo.meta["robot_id"]`), `robot_ids`
keeps those of some robots only, and the summary and the stored reward's info count the
demonstrations per robot (`demonstrations_per_robot`).

Every failure to read or write a source is an LfdError (DemonstrationError when no usable
demonstration is found; RewardNotAcceptedError for a person or hallway reward refused by its
acceptance check), which `main` turns into one `ERROR:` line and exit status 1.
"""
import json
import sys
import time
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import yaml
from std_msgs.msg import String

from lfd_controller import ros_demos
from lfd_controller.demos import Demonstration
from lfd_controller.errors import DemonstrationError, LfdError
from lfd_controller.hallway import calibrate_pace, fit_hallway_reward
from lfd_controller.hallway_recording import RecordedSensors, moving_speed, recorded_windows
from lfd_controller.learning import RewardNotAcceptedError, learn_and_save, save_reward
from lfd_controller.params import LearnRewardParams
from lfd_controller.recorded_check import check_recorded
from robot_common.errors import ConfigError
from ros_mongo import StoreError, open_store, redact_url

NO_ROBOT = "(no robot id)"  # database demonstrations recorded without a robot id
FROM_BAGS = "(bags)"        # demonstrations read from bag files


def load_database_demos(store, *, scenario: str = "", session_id: str = "",
                        robot_ids: Sequence[str] = ()) -> List[Demonstration]:
    """Stored demonstrations, oldest first (of one scenario, session and of some robots, if
    given), each with the robot that recorded it in `meta["robot_id"]` ("" if none)."""
    tags = ["demonstration"] + ([scenario] if scenario else [])
    demos = []
    for robot_id in list(robot_ids) or [None]:
        for stored in store.find_messages(topic=ros_demos.DEMO_TOPIC, tags=tags,
                                          session_id=session_id or None, robot_id=robot_id):
            demo = ros_demos.from_msg(stored.message())
            demo.meta["robot_id"] = stored.robot_id or ""
            demos.append(demo)
    return demos


def load_sources(bags: Sequence[str], db_url: str = "", scenario: str = "",
                 session_id: str = "", robot_ids: Sequence[str] = ()) -> List[Demonstration]:
    """Demonstrations from bag files/folders and the database (of one session, and recorded by
    one of `robot_ids`, if given: a fleet's central database holds every robot's)."""
    demos = ros_demos.read_bags(bags) if bags else []
    if db_url:
        try:
            with open_store(db_url) as store:
                demos += load_database_demos(store, scenario=scenario, session_id=session_id,
                                             robot_ids=robot_ids)
        except StoreError as err:
            raise DemonstrationError(f"cannot load demonstrations from {redact_url(db_url)}: "
                                     f"{err}") from err
    if scenario:
        demos = [d for d in demos if d.scenario.name == scenario]
    if not demos:
        where = f" for scenario {scenario!r}" if scenario else ""
        robots = f" recorded by {', '.join(robot_ids)}" if robot_ids else ""
        raise DemonstrationError(f"no demonstrations found{where}{robots}")
    return demos


def demos_per_robot(demos: Sequence[Demonstration]) -> Dict[str, int]:
    """How many demonstrations each robot recorded (database ones without a robot id under
    NO_ROBOT, those from bags under FROM_BAGS), by robot id."""
    counts: Dict[str, int] = {}
    for demo in demos:
        robot = demo.meta.get("robot_id")
        robot = FROM_BAGS if robot is None else robot or NO_ROBOT
        counts[robot] = counts.get(robot, 0) + 1
    return dict(sorted(counts.items()))


def store_reward(reward, db_url: str, info: Optional[dict] = None) -> str:
    """Stores the reward (YAML in a std_msgs/String on /lfd/rewards); returns its database id."""
    try:
        with open_store(db_url) as store:
            text = yaml.safe_dump(dict(reward.to_dict(), info=info or {}), sort_keys=False)
            return store.insert_message(ros_demos.REWARD_TOPIC, String(data=text),
                                        tags=["reward", reward.kind])
    except StoreError as err:
        raise LfdError(f"cannot store the reward in {db_url}: {err}") from err


def read_building_drives(bags) -> Tuple[List[Tuple[Demonstration, RecordedSensors]], List[str]]:
    """(demonstration, what the robot saw) of each building drive in the bags, and a name for
    each (its bag's); DemonstrationError when there is none."""
    drives, names = [], []
    for path in ros_demos.bag_files(bags):
        found = ros_demos.read_building_bags([path])
        drives += found
        names += [path.name] * len(found)
    if not drives:
        raise DemonstrationError("no building demonstrations (bags with /path, /scan and /people "
                                 "beside the steps; the database keeps the steps only) in "
                                 f"{list(bags)}")
    return drives, names


def learn_building_reward(bags, *, output: str, seed: int = 0, accept_mismatch: bool = False,
                          progress: Callable[[str], None] = lambda _: None) -> str:
    """A hallway reward from building drives recorded in bags (the steps with the path, scans
    and tracked people the recorder kept): CIOC on their 4 s windows (fit_hallway_reward), the
    pace set to the drives' median moving speed (calibrate_pace); then the acceptance check on
    the recordings themselves (recorded_check.check_recorded: the controller with the barrier
    margin of the person's room drives each recording's start along its path, on a map built
    from its scans among its replayed people). A reward refused there is not saved
    (RewardNotAcceptedError names the failing drives) unless `accept_mismatch` (then the file
    says so). The file's info holds the verdict and `controller: {barrier_margin}`. The scans
    are taken as seen from the base (a laser ahead of it shifts the scan points)."""
    drives, names = read_building_drives(bags)
    started = time.monotonic()
    progress(f"learning from {len(drives)} building drives")
    windows = []
    for name, (demo, sensors) in zip(names, drives):
        try:
            windows += recorded_windows(demo, sensors)
        except DemonstrationError as err:
            raise DemonstrationError(f"{name}: {err}") from err
    reward, learner = fit_hallway_reward(windows, seed)
    reward = calibrate_pace(reward, moving_speed([demo for demo, _ in drives]))
    seconds = time.monotonic() - started
    progress(f"learned from {len(windows)} windows in {seconds:.1f} s; the acceptance check "
             f"drives the controller through the {len(drives)} recordings")
    checked = check_recorded(reward, drives, names=names, progress=progress)
    if not checked.accepted and not accept_mismatch:
        raise RewardNotAcceptedError(checked)
    verdict = checked.to_dict()
    if not checked.accepted:
        verdict["saved_anyway"] = "refused by the acceptance check, saved with --accept-mismatch"
    path = save_reward(reward, output, demonstrations=len(drives), windows=len(windows),
                       learning_seconds=round(seconds, 2),
                       log_likelihood_per_demo=float(learner.log_likelihood_),
                       acceptance=verdict,
                       controller={"barrier_margin": round(checked.margin, 4)})
    state = ("accepted: " if checked.accepted else
             "saved although NOT accepted (--accept-mismatch): "
             + "; ".join(checked.failure_lines()) + " | ")
    return (f"learned a hallway reward from {len(drives)} building drives ({len(windows)} windows) "
            f"in {seconds:.1f} s -> {path}\n{state}" + "; ".join(checked.drive_lines())
            + "\nweights: "
            + json.dumps(reward.to_dict()["weights"]))


def learn_from_sources(bags, db_url: str = "", *, scenario: str = "", session_id: str = "",
                       robot_ids: Sequence[str] = (), kind: str = "linear", output: str,
                       store_db: bool = False, plots: str = "", seed: int = 0,
                       trim_steps: Optional[int] = 10, accept_mismatch: bool = False,
                       progress: Callable[[str], None] = lambda _: None) -> str:
    """Load, learn, save (store with `store_db` and a `db_url`, and plot); returns a summary
    whose last line counts the demonstrations per robot (also in the stored reward's info).
    `progress` gets lines while a hallway reward is checked."""
    if kind == "hallway":
        return learn_building_reward(bags, output=output, seed=seed,
                                     accept_mismatch=accept_mismatch, progress=progress)
    demos = load_sources(bags, db_url, scenario, session_id, robot_ids)
    per_robot = demos_per_robot(demos)

    def store(reward, info):
        return store_reward(reward, db_url, dict(info, demonstrations_per_robot=per_robot))

    summary = learn_and_save(demos, kind=kind, output=output, plots=plots, seed=seed,
                             trim_steps=trim_steps, store=store if store_db and db_url else None,
                             accept_mismatch=accept_mismatch)
    robots = ", ".join(f"{robot}: {count}" for robot, count in per_robot.items())
    return f"{summary}\ndemonstrations per robot: {robots}"


def _progress(line: str) -> None:
    print(f"learn_reward: {line}", file=sys.stderr, flush=True)


def main(argv: Optional[Sequence[str]] = None) -> int:
    """learn_reward's command line (options: params.LearnRewardParams; --help lists them)."""
    args = [a for a in (sys.argv[1:] if argv is None else argv) if not a.startswith("__")]
    try:
        config = LearnRewardParams.from_args(args)
        summary = learn_from_sources(config.bags, config.db_url, scenario=config.scenario,
                                     session_id=config.session_id, robot_ids=config.robot_ids,
                                     kind=config.kind, output=config.output, store_db=config.store_db,
                                     plots=config.plots, seed=config.seed, trim_steps=config.trim,
                                     accept_mismatch=config.accept_mismatch,
                                     progress=_progress)
    except (ConfigError, LfdError) as err:
        print(f"ERROR: {err}", file=sys.stderr)
        return 1
    print(summary)
    return 0
