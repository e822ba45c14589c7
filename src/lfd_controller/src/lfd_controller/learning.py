"""Learning a reward from demonstrations end to end: fit, save, load, plot (no ROS).

The pipeline takes demonstrations already loaded; reading them from bags and the database, and
storing the learned reward there, is the `learn_reward` module's, which hands `learn_and_save` a
`store` callable. Reward files are YAML written by `save_reward`; `load_reward` raises
RewardFileError when one is missing or malformed.
"""
import json
import time
from pathlib import Path
from typing import Any, Callable, Dict, Optional, Sequence

import yaml
from threadpoolctl import threadpool_limits

from lfd_controller import plots as plotting
from lfd_controller.acceptance import Acceptance, calibrate, goal_reaching
from lfd_controller.cioc import LinearCIOC
from lfd_controller.demos import Demonstration, demos_summary, trim_to_goal, windows
from lfd_controller.errors import LearningError, LfdError, RewardFileError
from lfd_controller.features import FeatureSet
from lfd_controller.gp_cioc import GPCIOC
from lfd_controller.planner import CollisionBarrier, RecedingHorizonController
from lfd_controller.rewards import reward_from_dict

# store(reward, info) -> where the reward was stored (a database id)
RewardStore = Callable[[object, Dict], str]


def person_features() -> FeatureSet:
    """The feature set for demonstrations people give with a joystick (README "Learning from
    people"): progress toward the goal per step (v cos(bearing to goal): the same pull at any
    distance, none at the goal) instead of the summed goal distance, the goal heading, the
    obstacle's proximity at three fall-off lengths (0.35, 0.5, 0.8 m) and 1 s ahead (a smooth
    time-to-collision), the obstacle-between-me-and-the-goal feature, and the squared commands."""
    return FeatureSet(goal_distance=True, goal_progress=True, proximity_widths=(0.5, 0.8),
                      predicted=1.0, state_effort=True)


# What the person features mean: progress and facing the goal are never worse, nearness to the
# obstacle and effort never better.
PERSON_SIGNS = {"goal_distance": -1, "goal_heading": 1, "goal_progress": 1, "obstacle_proximity": -1,
                "obstacle_proximity_0.5": -1, "obstacle_proximity_0.8": -1, "obstacle_ahead": -1,
                "obstacle_predicted": -1, "speed_squared": -1, "turn_squared": -1,
                "speed_effort": -1, "turn_effort": -1}
# Command noise of a joystick (quantised stick, hand): learned with the weights.
PERSON_NOISE = "learn"


def fit_reward(demos: Sequence[Demonstration], kind: str = "linear", seed: int = 0,
               features: Optional[FeatureSet] = None, signs: Optional[dict] = None,
               action_noise=None):
    """(reward, learner) from demonstrations with the linear or GP CIOC (features: default
    FeatureSet(); signs and action_noise: LinearCIOC's)."""
    if kind not in ("linear", "gp"):
        raise LfdError(f"reward kind must be 'linear' or 'gp', got {kind!r}")
    learner = (LinearCIOC(features, random_state=seed, signs=signs, action_noise=action_noise)
               if kind == "linear" else GPCIOC(features, random_state=seed))
    with threadpool_limits(1):      # small matrices: BLAS threads only contend (10x slower under load)
        learner.fit(list(demos))
    return learner.reward_, learner


# How person demonstrations are learned from (README "Learning from people"): cut into 4 s windows
# every 2 s, each a locally optimal plan from the recorded state where it starts (a person
# re-decides continuously, as the receding-horizon controller does); the Gauss-Newton Hessian (the
# acceleration limit's curvature makes the exact H indefinite under a jittery stick); command noise
# learned with the weights.
PERSON_WINDOW, PERSON_STRIDE = 40, 20
# Steps kept after a person demo first reaches the goal (sitting still there is part of it).
PERSON_TRIM = 0
# How the controller drives with a person reward: 20 steps of 0.4 s (8 s: far enough to see past
# the obstacle - at 4 s stopping in front of it ranks above going round), no terminal weight (the
# progress feature's sum is already the distance made good), detour seeds 0.8 m beside the obstacle,
# one alternative seed per cycle (an even cycle time), discount 0.97 per step (without it, once the
# goal is within the 8 s look-ahead the progress sum no longer grows with speed and the plan crawls
# in, timing out slow styles; chosen on validation starts), and an arrival look-ahead of at least
# 8 steps (min_horizon: the plan ends about when the robot would arrive at the reward's preferred
# speed, as the learned windows do, so the last metres are not spread over 8 s; validation starts),
# and an absorbing goal region of the scenarios' goal tolerance (arrival 0.25 m: after arrival a
# plan step is worth resting at the goal, so no effort cost accrues there; without it the shorter
# look-ahead let the speed/turn costs stretch the last metres into a creep past the region's
# edge: sporty static 15/20 -> 20/20 validation starts), and after 1.5 s standing still away from
# the goal a detour past the obstacle (unstall: the plan's local optimum straight in front of a
# static obstacle is stable once the calibrated reward drives at a slow person's pace), counted
# from the first plan that ends standing there (stall_plans: a slow person's reward crept 3 s
# toward that stop before it stood), and a seed heading straight for the goal at full speed
# (goal_seed: the turning seeds start along the robot's heading, and from a start facing away
# from the goal they all settled on waiting for an oscillating obstacle to sweep past and come
# back, where the reward ranked slipping past it, as the person did, higher; chosen on the
# validation and development people) (RecedingHorizonController options).
PERSON_CONTROLLER = {"horizon": 20, "plan_dt": 0.4, "terminal": 0.0, "detour": 0.8,
                     "spread_seeds": True, "discount": 0.97, "min_horizon": 8, "arrival": 0.25,
                     "unstall": 1.5, "stall_plans": True, "goal_seed": 1.0}
# What reward_controller needs to drive a person reward (saved with it, `controller:` in the file):
# PERSON_CONTROLLER plus the fixed collision barrier (m beyond touching; planner.CollisionBarrier).
PERSON_DRIVING = dict(PERSON_CONTROLLER, collision_margin=0.1)


def person_driving(margin: float = PERSON_DRIVING["collision_margin"]) -> Dict[str, Any]:
    """PERSON_DRIVING with the collision barrier `margin` m beyond touching and the detour seeds
    moved out by as much as the margin grew (they must pass outside the barrier)."""
    grown = max(0.0, margin - PERSON_DRIVING["collision_margin"])
    return dict(PERSON_DRIVING, collision_margin=round(float(margin), 4),
                detour=round(PERSON_DRIVING["detour"] + grown, 4))


def person_controller(reward, scenario, *, budget: Optional[float] = 0.1,
                      settings: Optional[Dict[str, Any]] = None) -> RecedingHorizonController:
    """The receding-horizon controller that drives a person reward in `scenario`: `settings`
    (default PERSON_DRIVING; a learned reward's are `learner.driving_`, saved with it) with the
    CollisionBarrier, a cycle budget of `budget` s."""
    settings = dict(PERSON_DRIVING if settings is None else settings)
    margin = float(settings.pop("collision_margin", 0.0))
    planned = CollisionBarrier(reward, scenario.clearance, margin=margin) if margin > 0 else reward
    return RecedingHorizonController(planned, scenario.model(), budget=budget, **settings)


# Controller-in-the-loop calibration (acceptance.calibrate): rounds of the controller's own drives
# from up to max_drives demonstration starts, then the verdict on the best round's drives plus
# `nearby` starts around each (4 + 8 = 12 drives: one missed drive does not refuse). The check's
# controller has no cycle budget, so its verdict does not depend on how busy the machine is
# while learning. The check's controller knows the obstacle as reward_controller does on a robot,
# from its odometry at constant velocity (prediction "tracked"): calibrated knowing the scenario's
# future instead, a reward that kept the person's pace there slipped past a sweeping obstacle 0.3-
# 0.8 s later on a robot (chosen on the validation and development people).
PERSON_CALIBRATION = {"rounds": 4, "max_drives": 4, "nearby": 2, "prediction": "tracked"}


def fit_person_reward(demos: Sequence[Demonstration], seed: int = 0, *, calibration: Optional[Dict] = None,
                      progress: Optional[Callable] = None):
    """(reward, learner): linear CIOC over person_features() with PERSON_SIGNS and learned command
    noise, from demonstrations cut where they first reach the goal, in PERSON_WINDOW-step windows;
    then the controller's own drives from the demonstrations' starts are compared with the
    demonstrations and the reward's speed and obstacle scales and the collision barrier's margin
    refined (acceptance.calibrate; calibration: its options, default PERSON_CALIBRATION;
    {"rounds": 0}: no check). The report is `learner.acceptance_` (None without a check), the
    controller settings to drive the reward with `learner.driving_` (person_driving),
    `learner.cioc_reward_` is CIOC's own reward. NoGoalError when no demonstration reaches
    the goal."""
    demos = list(demos)
    reaching = goal_reaching(demos)
    pieces = [piece for demo in demos
              for piece in windows(trim_to_goal(demo, PERSON_TRIM), PERSON_WINDOW, PERSON_STRIDE)]
    learner = LinearCIOC(person_features(), random_state=seed, signs=PERSON_SIGNS,
                         action_noise=PERSON_NOISE, second_order=False)
    with threadpool_limits(1):
        learner.fit(pieces)
        reward, learner.cioc_reward_, learner.acceptance_ = learner.reward_, learner.reward_, None
        learner.driving_ = dict(PERSON_DRIVING)
        options = dict(PERSON_CALIBRATION, **(calibration or {}))
        if options["rounds"] > 0:
            reward, learner.acceptance_ = calibrate(
                reward, reaching,
                lambda r, scenario, margin: person_controller(r, scenario, budget=None,
                                                              settings=person_driving(margin)),
                progress=progress, **options)
            learner.driving_ = person_driving(learner.acceptance_.scales["margin"])
    return reward, learner


class RewardNotAcceptedError(LearningError):
    """The acceptance check refused the learned reward: its controller fails where the person
    succeeded, or no demonstration gives it anything to be held to (see `acceptance`)."""

    def __init__(self, acceptance: Acceptance):
        super().__init__("the learned reward was NOT saved: the acceptance check refused it ("
                         + "; ".join(acceptance.failure_lines()) + "). "
                         + acceptance.describe())
        self.acceptance = acceptance


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


def controller_settings(path) -> Dict[str, Any]:
    """The controller settings saved with a reward (`info.controller`; {} when there are none)."""
    try:
        data = yaml.safe_load(Path(path).read_text()) or {}
    except (OSError, yaml.YAMLError) as err:
        raise RewardFileError(f"cannot read reward file {path}: {err}") from err
    settings = (data.get("info") or {}).get("controller") or {}
    if not isinstance(settings, dict):
        raise RewardFileError(f"reward file {path}: info.controller must be a mapping")
    return dict(settings)


def learn_and_save(demos: Sequence[Demonstration], *, kind: str = "linear", output: str,
                   plots: str = "", seed: int = 0, trim_steps: Optional[int] = 10,
                   store: Optional[RewardStore] = None, accept_mismatch: bool = False,
                   calibration: Optional[Dict] = None) -> str:
    """Learn, save (store, plot); returns a summary. kind "linear" or "gp" (default features) or
    "person" (fit_person_reward: drive it with PERSON_DRIVING, saved with it). Demos are cut
    `trim_steps` after first reaching the goal (None: uncut), so idling after a drive does not
    count as demonstrated behaviour; `store(reward, info)`, when given, also keeps the reward
    elsewhere. A person reward whose controller fails where the person succeeded
    (acceptance.calibrate: does not reach, collides, crawls, cuts closer to a moving obstacle) is
    not saved: RewardNotAcceptedError says why, unless accept_mismatch (then saved with the
    report in its info); one that only drives a little differently is saved with the report and
    a WARNING line in the summary."""
    demos = list(demos)
    if trim_steps is not None:
        demos = [trim_to_goal(d, trim_steps) for d in demos]
    started = time.monotonic()
    if kind == "person":
        reward, learner = fit_person_reward(demos, seed, calibration=calibration)
    else:
        reward, learner = fit_reward(demos, kind, seed)
    seconds = time.monotonic() - started
    info = {"demonstrations": len(demos), "steps": int(sum(d.length for d in demos)),
            "learning_seconds": round(seconds, 2), "beta": float(learner.beta_),
            "log_likelihood_per_demo": float(learner.log_likelihood_)}
    acceptance = getattr(learner, "acceptance_", None)
    if acceptance is not None:
        if not acceptance.accepted and not accept_mismatch:
            raise RewardNotAcceptedError(acceptance)
        info["acceptance"] = _plain(acceptance.to_dict())
    if kind == "person":
        info["controller"] = dict(learner.driving_)
    path = save_reward(reward, output, **info)
    lines = [f"learned a {kind} reward from {demos_summary(demos)} in {seconds:.1f} s -> {path}"]
    if acceptance is not None:
        lines.append(("accepted: " if acceptance.accepted else "saved although NOT accepted "
                      "(--accept-mismatch): ") + acceptance.describe())
        if acceptance.warning():
            lines.append(acceptance.warning())
    if kind in ("linear", "person"):
        lines.append("weights: " + json.dumps(reward.to_dict()["weights"]))
    if store is not None:
        lines.append(f"stored in the database as {store(reward, info)}")
    if plots:
        folder = Path(plots)
        lines.append("plots: " + ", ".join(str(p) for p in (
            plotting.plot_demonstrations(demos, folder / "demonstrations.png"),
            plotting.plot_reward_field(reward, demos[0].scenario, folder / "reward_field.png", demos))))
    return "\n".join(lines)


def _plain(value):
    """Plain Python values (YAML-safe) from a report of numpy scalars."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "item"):
        return value.item()
    return value
