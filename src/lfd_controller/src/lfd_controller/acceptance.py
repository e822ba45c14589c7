"""Does the learned controller drive like the demonstrations? Check, calibrate, accept (no ROS).

A reward learned from a person is only useful if the controller that plans with it gets where the
person got, as safely and not much slower. This module drives the controller itself and decides
on evidence:

  * **drives**: from the demonstrations' own starts (up to `max_drives`) and from `nearby` starts
    around each of them (a little to the side, turned a little), at the demonstration's episode
    time - enough drives that one unlucky drive does not decide;
  * **refused** (`Acceptance.failures`) only where the controller fails where the person
    succeeded: it reaches the goal from fewer than `reach_fraction` (80 %) of the starts the
    person reached it from (one missed drive in 12 does not refuse), it collides, it crawls
    (median mean speed under 0.6 x the person's or median time to goal over 1.5 x), or it passes
    closer to a **moving** obstacle than the person ever did (by more than `room_tolerance`,
    0.05 m): the room a person keeps around something that moves is theirs to choose;
  * **mismatches** (`Acceptance.matched`, saved with a warning line): mean speed within 20 %,
    time to goal at most 25 % longer (arriving sooner, by a shorter way at the person's speed, is
    not a mismatch: the speed says whether it drives faster), closest approach within 0.1 m, the
    goal as often as the person.

`calibrate` refines three interpretable settings with the controller in the loop (at most
`rounds` drives of the demonstrated starts): the speed penalties (speed_squared, speed_effort)
and, where it speeds the controller up, the turn penalties (the same path at a faster pace) are
divided by a scale found by a secant step toward a target speed: the demonstrated speed, or,
where the controller's own path is longer than the person's, a speed between that and the one
that would give the demonstrated time on it (never below the person's own speed: a person whose
takes wander takes long, not slowly); the rounds go on until the speed is no more than `AIM`
below the person's and the time no more than `AIM` longer (closer than the warnings'
tolerances: the pace on a handful of starts is a noisy estimate of the pace on new ones); the
collision barrier's margin follows the gap in closest approach; the obstacle terms (proximity,
ahead, predicted) are scaled down when the controller keeps more room than the person even with
the margin at its lower bound, or waits instead of arriving. Around a moving obstacle neither may
give up room the person kept: the margin never goes below the person's closest approach less
0.05 m, and the obstacle terms are not scaled down once the controller comes as close as the
person did. The best round (no failure, then most statistics matched, then the smallest
mismatch) is then driven from the nearby starts too, and the verdict is on all its drives.

Rollouts here are the controller's own check, not a simulator: they step the same unicycle model
the controller plans with, replanning every `replan_every` control steps (the plan's first
command spans a planning step of 0.4 s, so replanning every 0.2 s changes little and halves the
cost). The controller knows the obstacle's future as `prediction` says: as the scenario has it,
or as a robot's node tracks it (`Task.tracked`: its position and velocity at 10 Hz, kept constant,
with an allowance for the changes of velocity it showed), so that the check holds the controller
to the person's pace as it will drive on a robot.
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
# Divided with the speed penalties when those are (a faster pace): at s times the speed, the same
# path turns s times as fast, so only penalties on turning scaled alike keep the way the person
# shapes their path round the obstacle and into the goal (with the speed penalties alone divided,
# a fast controller's arcs widened until it passed the goal and crawled beside it). Never made
# dearer than learned (a slower pace): stiffer turning held the robot in front of the obstacle.
TURN_TERMS = ("turn_squared", "turn_effort")
# The collision barrier's margin beyond touching (m): never below the fixed safety margin.
MARGIN_BOUNDS = (0.1, 0.5)
OBSTACLE_PREFIXES = ("obstacle_",)
STATISTICS = ("mean_speed", "time", "closest")
# What refuses a reward: the controller fails where the person succeeded.
FAILURES = ("reach", "collision", "crawl", "room")
# The verdict's thresholds (acceptance.verdict); the calibration's targets are `compare`'s.
VERDICT = {"reach_fraction": 0.8, "crawl_speed": 0.6, "crawl_time": 1.5, "room_tolerance": 0.05}
# The calibration's aim (relative): it stops early only when the driven mean speed is no more than
# this much below the person's (above it, the warning's tolerance holds: slowing a controller down
# to the last few per cent can make it stall) and the time to goal no more than this much longer.
AIM = 0.1
# What a checked controller knows of the obstacle's future (`drive`)
PREDICTIONS = ("scenario", "tracked")


class NoGoalError(LearningError):
    """None of the person's demonstrations reaches the goal: there is nothing to match."""


def trajectory_statistics(scenario, trajectory, t0: float = 0.0) -> Dict[str, float]:
    """{mean_speed, time, closest, reached, collided} of x_0..x_T (every scenario.dt from episode
    time t0): time to the goal region (the scenario's max_time when never reached), mean speed
    until then, closest approach to the obstacle beyond touching until then."""
    trajectory = np.asarray(trajectory, float)
    times = t0 + scenario.dt * np.arange(len(trajectory))
    inside = np.flatnonzero(scenario.reached(trajectory))
    reached = bool(len(inside))
    end = int(inside[0]) if reached else len(trajectory) - 1
    path = float(np.sum(np.hypot(*np.diff(trajectory[:end + 1, :2], axis=0).T))) if end else 0.0
    duration = (times[end] - t0) if reached else max(scenario.max_time - t0, times[-1] - t0)
    gaps = scenario.obstacle_distance(trajectory[:end + 1], times[:end + 1]) - scenario.clearance
    collided = bool(np.any(scenario.collides(trajectory[:end + 1], times[:end + 1])))
    return {"mean_speed": path / max(duration, scenario.dt), "time": float(duration),
            "closest": float(gaps.min()), "reached": reached, "collided": collided}


def demonstration_statistics(demos: Sequence[Demonstration]) -> List[Dict[str, float]]:
    return [trajectory_statistics(d.scenario, trim_to_goal(d).trajectory(), d.t0) for d in demos]


def summarise(stats: Sequence[Dict]) -> Dict[str, float]:
    """Medians of the statistics (speed and time over the drives that reached the goal, when
    any did), the smallest closest approach, the fractions that reached the goal and collided."""
    arrived = [s for s in stats if s["reached"]] or list(stats)
    out = {key: float(np.median([s[key] for s in arrived])) for key in ("mean_speed", "time")}
    out["closest"] = float(np.median([s["closest"] for s in stats]))
    out["closest_min"] = float(min(s["closest"] for s in stats))
    out["reached"] = float(np.mean([s["reached"] for s in stats]))
    out["collided"] = float(np.mean([s.get("collided", False) for s in stats]))
    return out


def goal_reaching(demos: Sequence[Demonstration]) -> List[Demonstration]:
    """The demonstrations that reach the goal region without touching the obstacle;
    NoGoalError, one line saying so, when none does."""
    demos = list(demos)
    good = [d for d, s in zip(demos, demonstration_statistics(demos))
            if s["reached"] and not s["collided"]]
    if not good:
        scenario = demos[0].scenario if demos else None
        where = (f" (within {scenario.goal_tolerance:.2f} m of ({scenario.goal[0]:.2f}, "
                 f"{scenario.goal[1]:.2f}) in {scenario.name})") if scenario is not None else ""
        raise NoGoalError(f"none of the {len(demos)} demonstrations reaches the goal{where}: "
                          "there is no way to the goal to learn from; record drives that end at "
                          "the goal")
    return good


def nearby_starts(demo: Demonstration, count: int, rng, *, shift: float = 0.2,
                  turn: float = 0.2) -> List[np.ndarray]:
    """Up to `count` starts near the demonstration's: moved up to `shift` m (uniform in a disc)
    and turned up to `turn` rad, at rest, clear of the obstacle (0.1 m beyond touching) and the
    arena's walls at the demonstration's episode time."""
    scenario, found = demo.scenario, []
    for _ in range(20 * count):
        if len(found) >= count:
            break
        angle, radius = rng.uniform(-math.pi, math.pi), shift * math.sqrt(rng.uniform())
        state = np.array(demo.start, float).copy()
        state[0] += radius * math.cos(angle)
        state[1] += radius * math.sin(angle)
        yaw = state[2] + rng.uniform(-turn, turn)
        state[2] = math.atan2(math.sin(yaw), math.cos(yaw))
        state[3:] = 0.0
        if (not scenario.collides(state, demo.t0)
                and scenario.obstacle_distance(state, demo.t0) > scenario.clearance + 0.1):
            found.append(state)
    return found


@dataclass
class Acceptance:
    """The verdict on the controller's own drives: `failures` (FAILURES; any refuses the reward)
    and `matched` (the statistics the calibration aims at; a miss is a warning)."""

    demonstrated: Dict[str, float]
    driven: Dict[str, float]
    matched: Dict[str, bool]
    failures: Dict[str, bool] = field(default_factory=dict)
    scales: Dict[str, float] = field(default_factory=dict)
    rounds: int = 0
    drives: int = 0
    starts: Dict[str, int] = field(default_factory=dict)
    prediction: str = "scenario"

    @property
    def accepted(self) -> bool:
        return not any(self.failures.values())

    @property
    def exact(self) -> bool:
        """Accepted and every statistic matched (no warning)."""
        return self.accepted and all(self.matched.values())

    def _parts(self):
        d, c = self.demonstrated, self.driven
        return {"mean_speed": f"mean speed {c['mean_speed']:.2f} vs the person's {d['mean_speed']:.2f} m/s",
                "time": f"time to goal {c['time']:.1f} vs {d['time']:.1f} s",
                "closest": f"closest approach {c['closest']:.2f} vs {d['closest']:.2f} m (median)",
                "reached": f"reached the goal in {c['reached']:.0%} of {self.drives} drives "
                           f"(the person: {d['reached']:.0%})"}

    def failure_lines(self) -> List[str]:
        d, c, n = self.demonstrated, self.driven, self.drives
        text = {"reach": f"reaches the goal in only {c['reached']:.0%} of {n} drives from starts "
                         "the person reached it from",
                "collision": f"collides in {c['collided']:.0%} of {n} drives",
                "crawl": f"crawls: mean speed {c['mean_speed']:.2f} vs the person's "
                         f"{d['mean_speed']:.2f} m/s, time {c['time']:.1f} vs {d['time']:.1f} s",
                "room": f"passes {c['closest_min']:.2f} m from the moving obstacle where the "
                        f"person kept at least {d['closest_min']:.2f} m"}
        return [text[k] for k in FAILURES if self.failures.get(k)]

    def describe(self) -> str:
        parts = self._parts()
        matched = [parts[k] for k in parts if self.matched.get(k)]
        missed = [parts[k] for k in parts if not self.matched.get(k)]
        where = ", ".join(f"{v} {k}" for k, v in self.starts.items()) or "demonstration"
        knows = {"scenario": "the obstacle's motion known",
                 "tracked": "the obstacle tracked as on a robot"}[self.prediction]
        text = (f"controller's own drives from {self.drives} starts ({where}; {knows}; after "
                f"{self.rounds} calibration rounds): ")
        if not self.accepted:
            text += "FAILS where the person succeeded: " + "; ".join(self.failure_lines()) + " | "
        text += "matched: " + ("; ".join(matched) or "nothing")
        if missed:
            text += " | NOT matched: " + "; ".join(missed)
        return text

    def warning(self) -> str:
        """One line for a reward accepted with mismatches ('' when every statistic matched)."""
        missed = [v for k, v in self._parts().items() if not self.matched.get(k)]
        if not self.accepted or not missed:
            return ""
        return ("WARNING: the controller reaches the goal where the person did, without collisions "
                "or crawling, but does not drive quite like the person: " + "; ".join(missed))

    def to_dict(self) -> Dict:
        return {"accepted": self.accepted, "failures": dict(self.failures),
                "demonstrated": self.demonstrated, "driven": self.driven, "matched": self.matched,
                "warning": self.warning(), "scales": self.scales, "rounds": self.rounds,
                "drives": self.drives, "starts": dict(self.starts), "prediction": self.prediction}


def compare(demonstrated: Dict, driven: Dict, *, speed_tolerance: float = 0.2,
            time_tolerance: float = 0.25, closest_tolerance: float = 0.1) -> Dict[str, bool]:
    """Which statistics the drives match (the calibration's targets; a miss is a warning)."""
    return {"mean_speed": abs(driven["mean_speed"] - demonstrated["mean_speed"])
            <= speed_tolerance * demonstrated["mean_speed"],
            "time": driven["time"] <= (1.0 + time_tolerance) * demonstrated["time"],
            "closest": abs(driven["closest"] - demonstrated["closest"]) <= closest_tolerance,
            "reached": driven["reached"] >= demonstrated["reached"] - 0.2}


def verdict(demonstrated: Dict, driven: Dict, moving: bool, *, reach_fraction: float = 0.8,
            crawl_speed: float = 0.6, crawl_time: float = 1.5,
            room_tolerance: float = 0.05) -> Dict[str, bool]:
    """Where the controller fails where the person succeeded (FAILURES -> True): `driven` over
    starts the person reached the goal from (`demonstrated`: the person's own drives)."""
    return {"reach": driven["reached"] < reach_fraction * demonstrated["reached"] - 1e-9,
            "collision": driven["collided"] > 0.0,
            "crawl": (driven["mean_speed"] < crawl_speed * demonstrated["mean_speed"]
                      or driven["time"] > crawl_time * demonstrated["time"]),
            "room": moving and driven["closest_min"] < demonstrated["closest_min"] - room_tolerance}


def _check_prediction(prediction: str) -> None:
    if prediction not in PREDICTIONS:
        raise LearningError(f"prediction must be one of {PREDICTIONS}, got {prediction!r}")


def drive(controller, scenario, start, t0: float = 0.0, replan_every: int = 1,
          prediction: str = "scenario") -> np.ndarray:
    """The controller's drive x_0..x_T from `start` at episode time t0 in the scenario's model,
    until the goal region, a collision or the scenario's max_time. `prediction` is what the
    controller knows of the obstacle's future (PREDICTIONS): "scenario" its motion as the scenario
    has it, "tracked" what a robot's node has (Task.tracked)."""
    _check_prediction(prediction)
    model, task = scenario.model(), Task.from_scenario(scenario)
    controller.reset()
    state = np.asarray(start, float)
    states, command = [state], np.zeros(2)
    for k in range(max(1, int(round((scenario.max_time - t0) / scenario.dt)))):
        t = t0 + k * scenario.dt
        if k % replan_every == 0:
            seen = task if prediction == "scenario" else Task.tracked(scenario, t)
            command = controller.act(state, t, seen)
        state = model.step(state, command)
        states.append(state)
        if scenario.collides(state, t + scenario.dt) or scenario.reached(state):
            break
    return np.array(states)


def scaled(reward: LinearReward, speed: float, obstacle: float) -> LinearReward:
    """The reward with its speed penalties divided by `speed`, its turn penalties by
    max(`speed`, 1) (TURN_TERMS), and its obstacle terms times `obstacle`."""
    weights = reward.weights.copy()
    for i, name in enumerate(reward.features.names):
        if name in SPEED_TERMS:
            weights[i] /= speed
        elif name in TURN_TERMS:
            weights[i] /= max(speed, 1.0)
        elif name.startswith(OBSTACLE_PREFIXES):
            weights[i] *= obstacle
    return LinearReward(weights, reward.features)


def _drives(candidate, make_controller, margin, runs, replan_every, prediction):
    """Statistics of the controller's drives from (demo, start) pairs."""
    stats = []
    for demo, start in runs:
        controller = make_controller(candidate, demo.scenario, margin)
        trajectory = drive(controller, demo.scenario, start, demo.t0, replan_every, prediction)
        stats.append(trajectory_statistics(demo.scenario, trajectory, demo.t0))
    return stats


def calibrate(reward, demos: Sequence[Demonstration], make_controller: Callable, *, rounds: int = 3,
              max_drives: int = 6, nearby: int = 2, replan_every: int = 2, seed: int = 0,
              progress: Optional[Callable] = None, margin_bounds=MARGIN_BOUNDS,
              verdict_options: Optional[Dict] = None, prediction: str = "scenario", **tolerances):
    """(reward, Acceptance): the controller (make_controller(reward, scenario, margin)) driven from
    up to `max_drives` demonstration starts (demonstrations that reach the goal: NoGoalError when
    none does) for at most `rounds` rounds of calibration (speed and obstacle scales, barrier
    margin); the best round is then also driven from `nearby` starts around each, and the
    verdict (`verdict`, options `verdict_options`) is on all its drives. The margin starts at
    the demonstrations' median closest approach less 0.05 m, within `margin_bounds` (around a
    moving obstacle never below their smallest less 0.05 m); Acceptance.scales holds speed,
    obstacle and margin. Every drive knows the obstacle's future as `prediction` says (`drive`).
    """
    if not isinstance(reward, LinearReward):
        raise LearningError("calibration needs a linear reward")
    _check_prediction(prediction)
    demos = goal_reaching(demos)
    picks = np.linspace(0, len(demos) - 1, min(max_drives, len(demos))).round().astype(int)
    chosen = [demos[i] for i in sorted(set(picks.tolist()))]
    person = summarise(demonstration_statistics(demos))
    moving = any(d.scenario.obstacle.moving for d in chosen)
    floor = margin_bounds[0]
    if moving:       # the room the person keeps around a moving obstacle is not given up
        floor = float(np.clip(person["closest_min"] - 0.05, *margin_bounds))
    bounds = (floor, max(floor, margin_bounds[1]))
    scales = {"speed": 1.0, "obstacle": 1.0,
              "margin": float(np.clip(person["closest"] - 0.05, *bounds))}
    options = dict(VERDICT, **(verdict_options or {}))
    best, history = None, []
    for round_ in range(1, max(1, rounds) + 1):
        candidate = scaled(reward, scales["speed"], scales["obstacle"])
        stats = _drives(candidate, make_controller, scales["margin"],
                        [(d, d.start) for d in chosen], replan_every, prediction)
        driven = summarise(stats)
        matched = compare(person, driven, **tolerances)
        failures = verdict(person, driven, moving, **options)
        report = Acceptance(person, driven, matched, failures,
                            {k: round(v, 4) for k, v in scales.items()}, round_, len(chosen),
                            {"demonstrated": len(chosen)}, prediction)
        score = (not any(failures.values()), sum(matched.values()), -_mismatch(person, driven))
        if best is None or score > best[0]:
            best = (score, candidate, report, stats, dict(scales))
        if progress is not None:
            progress(report)
        if report.accepted and on_target(person, driven, **tolerances):
            break
        history.append((math.log(scales["speed"]), math.log(max(driven["mean_speed"], 0.02))))
        scales = _next_scales(person, driven, matched, history, scales, bounds, moving)
    _, candidate, report, stats, scales = best
    rng = np.random.default_rng(seed)
    runs = [(d, start) for d in chosen for start in nearby_starts(d, nearby, rng)]
    stats = stats + _drives(candidate, make_controller, scales["margin"], runs, replan_every,
                            prediction)
    driven = summarise(stats)
    report = Acceptance(person, driven, compare(person, driven, **tolerances),
                        verdict(person, driven, moving, **options), report.scales, round_,
                        len(stats), {"demonstrated": len(chosen), "nearby": len(runs)}, prediction)
    if progress is not None:
        progress(report)
    return candidate, report


def paced(demonstrated: Dict, driven: Dict, aim: float = AIM, **tolerances) -> bool:
    """The calibration's aim for the pace: mean speed no more than `aim` below the person's (and
    within the warning's speed tolerance above it: `compare`'s, or the caller's), time to goal at
    most `aim` longer."""
    matched = compare(demonstrated, driven, **dict(tolerances, time_tolerance=aim))
    return (matched["mean_speed"] and matched["time"]
            and driven["mean_speed"] >= (1.0 - aim) * demonstrated["mean_speed"])


def on_target(demonstrated: Dict, driven: Dict, aim: float = AIM, **tolerances) -> bool:
    """Where the calibration stops: `paced`, and the room and the goal as `compare` (with the
    warnings' `tolerances`) has them."""
    matched = compare(demonstrated, driven, **tolerances)
    return paced(demonstrated, driven, aim, **tolerances) and matched["closest"] and matched["reached"]


def _mismatch(demonstrated: Dict, driven: Dict) -> float:
    return (abs(math.log(max(driven["mean_speed"], 1e-3) / max(demonstrated["mean_speed"], 1e-3)))
            + max(0.0, math.log(driven["time"] / max(demonstrated["time"], 1e-3)))
            + abs(driven["closest"] - demonstrated["closest"]) / 0.1
            + 2.0 * max(0.0, demonstrated["reached"] - driven["reached"]))


def _next_scales(demonstrated, driven, matched, history, scales, margin_bounds, moving=False):
    """One refinement step from the last round's statistics. Speed scale: the secant in log-log
    space through the last two rounds (the first step assumes the driven speed proportional to
    the scale; steps at most x3 or /1.43: the speed falls steeply near a crawl). Room: the
    barrier's margin moves by the gap in closest approach (within margin_bounds); when it is at
    its lower bound and the controller still keeps too much room - or when it waits instead of
    arriving - the obstacle terms are scaled down by 1.5, except around a moving obstacle once
    the controller comes as close as the person ever did (then the room is the person's)."""
    scales = dict(scales)
    log_scale, log_speed = history[-1]
    if not paced(demonstrated, driven):
        slope = 1.0
        if len(history) > 1 and abs(history[-1][0] - history[-2][0]) > 1e-6:
            slope = (history[-1][1] - history[-2][1]) / (history[-1][0] - history[-2][0])
            slope = float(np.clip(slope, 0.2, 2.0))
        # the speed that matches the time on the controller's own path: on a longer path than
        # the person's, aim between it and the demonstrated speed (both tolerances hold there
        # when they can); on a shorter one, at the demonstrated speed (arriving sooner is fine)
        timed = driven["mean_speed"] * driven["time"] / max(demonstrated["time"], 1e-3)
        speed = max(demonstrated["mean_speed"], 0.02)
        target = math.sqrt(speed * timed) if timed > speed else speed
        wanted = math.log(target) - log_speed
        scales["speed"] = math.exp(log_scale) * float(np.clip(math.exp(wanted / slope), 0.7, 3.0))
    gap = demonstrated["closest"] - driven["closest"]
    slow = driven["mean_speed"] < 0.5 * demonstrated["mean_speed"]
    waiting = driven["reached"] < demonstrated["reached"] and slow
    close = moving and driven["closest_min"] <= demonstrated["closest_min"]
    if not matched["closest"] or waiting or close:
        margin = float(np.clip(scales["margin"] + gap, *margin_bounds))
        if not close and (waiting or (gap < 0 and margin - scales["margin"] > gap + 0.02)):
            scales["obstacle"] /= 1.5          # the margin could not take all of the excess room
            margin = min(margin, scales["margin"])
        scales["margin"] = margin
    return scales
