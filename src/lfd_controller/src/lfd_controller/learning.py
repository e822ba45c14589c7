"""Learning a reward from demonstrations end to end: fit, save, load, plot (no ROS).

The pipeline takes demonstrations already loaded; reading them from bags and the database, and
storing the learned reward there, is ROS-side (`ros_learning`), which hands `learn_and_save` a
`store` callable. Reward files are YAML written by `save_reward`; `load_reward` raises
RewardFileError when one is missing or malformed.
"""
import json
import time
from pathlib import Path
from typing import Callable, Dict, Optional, Sequence

import yaml
from threadpoolctl import threadpool_limits

from lfd_controller import plots as plotting
from lfd_controller.cioc import LinearCIOC
from lfd_controller.demos import Demonstration, demos_summary, trim_to_goal
from lfd_controller.errors import LfdError, RewardFileError
from lfd_controller.features import FeatureSet
from lfd_controller.gp_cioc import GPCIOC
from lfd_controller.rewards import reward_from_dict

# store(reward, info) -> where the reward was stored (a database id)
RewardStore = Callable[[object, Dict], str]


def person_features() -> FeatureSet:
    """The feature set for demonstrations people give with a joystick: the original features
    plus a preferred cruising speed (forward_command) and braking as one arrives (goal_slowing).
    See README "Learning from people" for why."""
    return FeatureSet(forward_command=True, goal_slowing=True)


# What the person features mean: far from the goal or near the obstacle is never better, nor is
# effort.
PERSON_SIGNS = {"goal_distance": -1, "obstacle_proximity": -1, "obstacle_ahead": -1,
                "goal_slowing": -1, "speed_effort": -1, "turn_effort": -1}


def fit_reward(demos: Sequence[Demonstration], kind: str = "linear", seed: int = 0,
               features: Optional[FeatureSet] = None, signs: Optional[dict] = None):
    """(reward, learner) from demonstrations with the linear or GP CIOC (features: default
    FeatureSet())."""
    if kind not in ("linear", "gp"):
        raise LfdError(f"reward kind must be 'linear' or 'gp', got {kind!r}")
    learner = (LinearCIOC(features, random_state=seed, signs=signs) if kind == "linear"
               else GPCIOC(features, random_state=seed))
    with threadpool_limits(1):      # small matrices: BLAS threads only contend (10x slower under load)
        learner.fit(list(demos))
    return learner.reward_, learner


def save_reward(reward, path, **info) -> Path:
    """Writes the reward (and `info`) as YAML; returns the path."""
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


def learn_and_save(demos: Sequence[Demonstration], *, kind: str = "linear", output: str,
                   plots: str = "", seed: int = 0, trim_steps: Optional[int] = 10,
                   store: Optional[RewardStore] = None) -> str:
    """Learn, save (store, plot); returns a summary. Demos are cut `trim_steps` after first
    reaching the goal (None: uncut), so idling after a drive does not count as demonstrated
    behaviour; `store(reward, info)`, when given, also keeps the reward elsewhere."""
    demos = list(demos)
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
    if store is not None:
        lines.append(f"stored in the database as {store(reward, info)}")
    if plots:
        folder = Path(plots)
        lines.append("plots: " + ", ".join(str(p) for p in (
            plotting.plot_demonstrations(demos, folder / "demonstrations.png"),
            plotting.plot_reward_field(reward, demos[0].scenario, folder / "reward_field.png", demos))))
    return "\n".join(lines)
