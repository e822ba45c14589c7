"""Does the learned controller drive like the demonstrations? Check, calibrate, accept (no ROS).

A reward learned from a person is only useful if the controller that plans with it drives as the
person did. This module drives the controller itself from the demonstrations' own starts and
compares three statistics with the demonstrations' (medians over drives):

  * mean speed until the goal region (path length / time): within `speed_tolerance` (20 %);
  * time to the goal region (a drive that does not arrive counts the scenario's whole time):
    within `time_tolerance` (25 %);
  * closest approach to the obstacle, beyond touching: within `closest_tolerance` (0.1 m);
  * and the goal reached in all but 20 % of the drives the demonstrations reached it from.

`calibrate` refines two interpretable scales of a linear reward with the controller in the loop
(at most `rounds` times): the speed penalties (speed_squared, speed_effort) are divided by a
scale found by a secant step toward a target speed between the demonstrated speed and the speed
that would give the demonstrated time on the controller's own path (its path may be shorter or
longer than the person's), so the reward's preferred speed moves to the person's pace; the
obstacle terms (proximity, ahead, predicted) are halved when the controller keeps much more room
than the person did or fails to arrive (waiting for the obstacle), doubled when it comes much
closer. The best round's reward is returned with an `Acceptance` report that
says which statistics were matched; the caller decides what to do with a reward that was not
(`learning.learn_and_save` refuses to save it).

Rollouts here are the controller's own check, not a simulator: they step the same unicycle model
the controller plans with, replanning every `replan_every` control steps (the plan's first
command spans a planning step of 0.4 s, so replanning every 0.2 s changes little and halves the
cost).
"""
import math
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence

import numpy as np

from lfd_controller.demos import Demonstration, trim_to_goal
from lfd_controller.errors import LearningError
from lfd_controller.features import Task
from lfd_controller.rewards import LinearReward

SPEED_TERMS = ("speed_squared", "speed_effort")
# The collision barrier's margin beyond touching (m): never below the fixed safety margin.
MARGIN_BOUNDS = (0.1, 0.5)
OBSTACLE_PREFIXES = ("obstacle_",)
STATISTICS = ("mean_speed", "time", "closest")


def trajectory_statistics(scenario, trajectory, t0: float = 0.0) -> Dict[str, float]:
    """{mean_speed, time, closest, reached} of x_0..x_T (every scenario.dt from episode time t0):
    time to the goal region (the scenario's max_time when never reached), mean speed until then,
    closest approach to the obstacle beyond touching until then."""
    trajectory = np.asarray(trajectory, float)
    times = t0 + scenario.dt * np.arange(len(trajectory))
    inside = np.flatnonzero(scenario.reached(trajectory))
    reached = bool(len(inside))
    end = int(inside[0]) if reached else len(trajectory) - 1
    path = float(np.sum(np.hypot(*np.diff(trajectory[:end + 1, :2], axis=0).T))) if end else 0.0
    duration = (times[end] - t0) if reached else max(scenario.max_time - t0, times[-1] - t0)
    gaps = scenario.obstacle_distance(trajectory[:end + 1], times[:end + 1]) - scenario.clearance
    return {"mean_speed": path / max(duration, scenario.dt), "time": float(duration),
            "closest": float(gaps.min()), "reached": reached}


def demonstration_statistics(demos: Sequence[Demonstration]) -> List[Dict[str, float]]:
    return [trajectory_statistics(d.scenario, trim_to_goal(d).trajectory(), d.t0) for d in demos]


def summarise(stats: Sequence[Dict]) -> Dict[str, float]:
    """Medians of the statistics, and the fraction of drives that reached the goal."""
    out = {key: float(np.median([s[key] for s in stats])) for key in STATISTICS}
    out["reached"] = float(np.mean([s["reached"] for s in stats]))
    return out


@dataclass
class Acceptance:
    """What the controller's own drives matched of the demonstrations' statistics."""

    demonstrated: Dict[str, float]
    driven: Dict[str, float]
    matched: Dict[str, bool]
    scales: Dict[str, float] = field(default_factory=dict)
    rounds: int = 0
    drives: int = 0

    @property
    def accepted(self) -> bool:
        return all(self.matched.values())

    def describe(self) -> str:
        d, c = self.demonstrated, self.driven
        parts = [f"mean speed {c['mean_speed']:.2f} vs demonstrated {d['mean_speed']:.2f} m/s",
                 f"time to goal {c['time']:.1f} vs {d['time']:.1f} s",
                 f"closest approach {c['closest']:.2f} vs {d['closest']:.2f} m",
                 f"reached the goal in {c['reached']:.0%} of {self.drives} drives"]
        marks = [self.matched[k] for k in STATISTICS] + [self.matched["reached"]]
        matched = [p for p, ok in zip(parts, marks) if ok]
        missed = [p for p, ok in zip(parts, marks) if not ok]
        text = (f"controller's own drives from {self.drives} demonstration starts "
                f"(after {self.rounds} calibration rounds): ")
        text += "matched: " + ("; ".join(matched) or "nothing")
        if missed:
            text += " | NOT matched: " + "; ".join(missed)
        return text

    def to_dict(self) -> Dict:
        return {"accepted": self.accepted, "demonstrated": self.demonstrated, "driven": self.driven,
                "matched": self.matched, "scales": self.scales, "rounds": self.rounds,
                "drives": self.drives}


def compare(demonstrated: Dict, driven: Dict, *, speed_tolerance: float = 0.2,
            time_tolerance: float = 0.25, closest_tolerance: float = 0.1) -> Dict[str, bool]:
    return {"mean_speed": abs(driven["mean_speed"] - demonstrated["mean_speed"])
            <= speed_tolerance * demonstrated["mean_speed"],
            "time": abs(driven["time"] - demonstrated["time"]) <= time_tolerance * demonstrated["time"],
            "closest": abs(driven["closest"] - demonstrated["closest"]) <= closest_tolerance,
            "reached": driven["reached"] >= demonstrated["reached"] - 0.2}


def drive(controller, scenario, start, t0: float = 0.0, replan_every: int = 1) -> np.ndarray:
    """The controller's drive x_0..x_T from `start` at episode time t0 in the scenario's model,
    until the goal region, a collision or the scenario's max_time."""
    model, task = scenario.model(), Task.from_scenario(scenario)
    controller.reset()
    state = np.asarray(start, float)
    states, command = [state], np.zeros(2)
    for k in range(max(1, int(round((scenario.max_time - t0) / scenario.dt)))):
        t = t0 + k * scenario.dt
        if k % replan_every == 0:
            command = controller.act(state, t, task)
        state = model.step(state, command)
        states.append(state)
        if scenario.collides(state, t + scenario.dt) or scenario.reached(state):
            break
    return np.array(states)


def scaled(reward: LinearReward, speed: float, obstacle: float) -> LinearReward:
    """The reward with its speed penalties divided by `speed` and its obstacle terms times
    `obstacle`."""
    weights = reward.weights.copy()
    for i, name in enumerate(reward.features.names):
        if name in SPEED_TERMS:
            weights[i] /= speed
        elif name.startswith(OBSTACLE_PREFIXES):
            weights[i] *= obstacle
    return LinearReward(weights, reward.features)


def calibrate(reward, demos: Sequence[Demonstration], make_controller: Callable, *, rounds: int = 3,
              max_drives: int = 6, replan_every: int = 2, progress: Optional[Callable] = None,
              margin_bounds=MARGIN_BOUNDS, **tolerances):
    """(reward, Acceptance): the controller (make_controller(reward, scenario, margin)) driven from
    up to `max_drives` demonstration starts, its statistics compared with the demonstrations',
    and the reward's speed and obstacle scales and the collision barrier's margin refined until
    they match (at most `rounds` drives of all starts); the best round (most statistics matched,
    then the smallest mismatch). The margin starts at the demonstrations' closest approach less
    0.05 m, within `margin_bounds`; Acceptance.scales holds speed, obstacle and margin."""
    if not isinstance(reward, LinearReward):
        raise LearningError("calibration needs a linear reward")
    demos = list(demos)
    if not demos:
        raise LearningError("calibration needs demonstrations")
    picks = np.linspace(0, len(demos) - 1, min(max_drives, len(demos))).round().astype(int)
    chosen = [demos[i] for i in sorted(set(picks.tolist()))]
    demonstrated = summarise(demonstration_statistics(chosen))
    scales = {"speed": 1.0, "obstacle": 1.0,
              "margin": float(np.clip(demonstrated["closest"] - 0.05, *margin_bounds))}
    best, history = None, []
    for round_ in range(1, max(1, rounds) + 1):
        candidate = scaled(reward, scales["speed"], scales["obstacle"])
        stats = []
        for demo in chosen:
            controller = make_controller(candidate, demo.scenario, scales["margin"])
            trajectory = drive(controller, demo.scenario, demo.start, demo.t0, replan_every)
            stats.append(trajectory_statistics(demo.scenario, trajectory, demo.t0))
        driven = summarise(stats)
        matched = compare(demonstrated, driven, **tolerances)
        report = Acceptance(demonstrated, driven, matched, {k: round(v, 4) for k, v in scales.items()},
                            round_, len(chosen))
        score = (sum(matched.values()), -_mismatch(demonstrated, driven))
        if best is None or score > best[0]:
            best = (score, candidate, report)
        if progress is not None:
            progress(report)
        if report.accepted:
            break
        history.append((math.log(scales["speed"]), math.log(max(driven["mean_speed"], 0.02))))
        scales = _next_scales(demonstrated, driven, matched, history, scales, margin_bounds)
    _, candidate, report = best
    report.rounds = round_
    return candidate, report


def _mismatch(demonstrated: Dict, driven: Dict) -> float:
    return (abs(math.log(max(driven["mean_speed"], 1e-3) / max(demonstrated["mean_speed"], 1e-3)))
            + abs(math.log(driven["time"] / max(demonstrated["time"], 1e-3)))
            + abs(driven["closest"] - demonstrated["closest"]) / 0.1
            + 2.0 * max(0.0, demonstrated["reached"] - driven["reached"]))


def _next_scales(demonstrated, driven, matched, history, scales, margin_bounds):
    """One refinement step from the last round's statistics. Speed scale: the secant in log-log
    space through the last two rounds (the first step assumes the driven speed proportional to
    the scale; steps at most x3 or /1.43: the speed falls steeply near a crawl). Room: the
    barrier's margin moves by the gap in closest
    approach; when it is at its lower bound and the controller still keeps too much room - or
    when it waits instead of arriving - the obstacle terms are scaled down by 1.5."""
    scales = dict(scales)
    log_scale, log_speed = history[-1]
    if not matched["mean_speed"] or not matched["time"]:
        slope = 1.0
        if len(history) > 1 and abs(history[-1][0] - history[-2][0]) > 1e-6:
            slope = (history[-1][1] - history[-2][1]) / (history[-1][0] - history[-2][0])
            slope = float(np.clip(slope, 0.2, 2.0))
        # the speed that matches the time on the controller's own (shorter or longer) path, and
        # the demonstrated speed: aim between them (both tolerances hold there when they can)
        timed = driven["mean_speed"] * driven["time"] / max(demonstrated["time"], 1e-3)
        target = math.sqrt(max(demonstrated["mean_speed"], 0.02) * max(timed, 0.02))
        wanted = math.log(target) - log_speed
        scales["speed"] = math.exp(log_scale) * float(np.clip(math.exp(wanted / slope), 0.7, 3.0))
    gap = demonstrated["closest"] - driven["closest"]
    slow = driven["mean_speed"] < 0.5 * demonstrated["mean_speed"]
    waiting = driven["reached"] < demonstrated["reached"] and slow
    if not matched["closest"] or waiting:
        margin = float(np.clip(scales["margin"] + gap, *margin_bounds))
        if waiting or (gap < 0 and margin - scales["margin"] > gap + 0.02):
            scales["obstacle"] /= 1.5          # the margin could not take all of the excess room
            margin = min(margin, scales["margin"])
        scales["margin"] = margin
    return scales
