"""Learning a reward from demonstrations end to end: load, fit, save (no ROS at import).

Bags and the database are read through ros_demos (imported only when asked for), so the core
stays usable without ROS.
"""
import json
import time
from pathlib import Path
from typing import List, Optional, Sequence

import yaml

from lfd_controller.cioc import LinearCIOC
from lfd_controller.demos import Demonstration, demos_summary, trim_to_goal
from lfd_controller.errors import DemonstrationError, LfdError, RewardFileError
from lfd_controller.gp_cioc import GPCIOC
from lfd_controller.rewards import reward_from_dict


def fit_reward(demos: Sequence[Demonstration], kind: str = "linear", seed: int = 0):
    """(reward, learner) from demonstrations with the linear or GP CIOC."""
    if kind not in ("linear", "gp"):
        raise LfdError(f"reward kind must be 'linear' or 'gp', got {kind!r}")
    from threadpoolctl import threadpool_limits

    learner = LinearCIOC(random_state=seed) if kind == "linear" else GPCIOC(random_state=seed)
    with threadpool_limits(1):      # small matrices: BLAS threads only contend (10x slower under load)
        learner.fit(list(demos))
    return learner.reward_, learner


def save_reward(reward, path, **info) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = dict(reward.to_dict(), info=info)
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def load_reward(path):
    """A reward from a file written by save_reward; RewardFileError when missing or malformed."""
    if not path:
        raise RewardFileError("no reward file given (parameter ~reward_file)")
    try:
        data = yaml.safe_load(Path(path).read_text())
    except OSError as err:
        raise RewardFileError(f"cannot read reward file {path}: {err.strerror}") from err
    except yaml.YAMLError as err:
        raise RewardFileError(f"reward file {path} is not YAML: {err}") from err
    return reward_from_dict(data)


def load_sources(bags: Sequence[str], db_url: str = "", scenario: str = "",
                 session_id: str = "") -> List[Demonstration]:
    """Demonstrations from bag files/folders and the database (of one session, if given)."""
    from lfd_controller import ros_demos

    demos = ros_demos.read_bags(bags) if bags else []
    if db_url:
        from ros_mongo import StoreError, open_store

        try:
            with open_store(db_url) as store:
                demos += ros_demos.load_demos(store, scenario=scenario or None,
                                              session_id=session_id or None)
        except StoreError as err:
            raise DemonstrationError(f"cannot load demonstrations from {db_url}: {err}") from err
    if scenario:
        demos = [d for d in demos if d.scenario.name == scenario]
    if not demos:
        where = f" for scenario {scenario!r}" if scenario else ""
        raise DemonstrationError(f"no demonstrations found{where}")
    return demos


def learn_from_sources(bags, db_url: str = "", *, scenario: str = "", session_id: str = "",
                       kind: str = "linear", output: str, store_db: bool = False, plots: str = "",
                       seed: int = 0, trim_steps: Optional[int] = 10) -> str:
    """Load, learn, save (and plot); demos are cut `trim_steps` after first reaching the goal
    (None: uncut), so idling after a drive does not count as demonstrated behaviour."""
    demos = load_sources(bags, db_url, scenario, session_id)
    if trim_steps is not None:
        demos = [trim_to_goal(d, trim_steps) for d in demos]
    started = time.monotonic()
    reward, learner = fit_reward(demos, kind, seed)
    seconds = time.monotonic() - started
    info = {"demonstrations": len(demos), "steps": int(sum(d.length for d in demos)),
            "learning_seconds": round(seconds, 2), "beta": float(learner.beta_),
            "log_likelihood_per_demo": float(learner.log_likelihood_)}
    path = save_reward(reward, output, **info)
    lines = [f"learned a {kind} reward from {demos_summary(demos)} in {seconds:.1f} s -> {path}"]
    if kind == "linear":
        lines.append("weights: " + json.dumps(reward.to_dict()["weights"]))
    if store_db and db_url:
        lines.append(f"stored in the database as {store_reward(reward, db_url, info)}")
    if plots:
        from lfd_controller import plots as plotting

        folder = Path(plots)
        lines.append("plots: " + ", ".join(str(p) for p in (
            plotting.plot_demonstrations(demos, folder / "demonstrations.png"),
            plotting.plot_reward_field(reward, demos[0].scenario, folder / "reward_field.png", demos))))
    return "\n".join(lines)


def store_reward(reward, db_url: str, info: Optional[dict] = None) -> str:
    from std_msgs.msg import String

    from lfd_controller.ros_demos import REWARD_TOPIC
    from ros_mongo import StoreError, open_store

    try:
        with open_store(db_url) as store:
            text = yaml.safe_dump(dict(reward.to_dict(), info=info or {}), sort_keys=False)
            return store.insert_message(REWARD_TOPIC, String(data=text), tags=["reward", reward.kind])
    except StoreError as err:
        raise LfdError(f"cannot store the reward in {db_url}: {err}") from err
