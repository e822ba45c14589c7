"""Trajectory optimisation of a reward through the unicycle dynamics, and the receding-horizon
controller that drives with a learned reward (no ROS).

The trajectory reward R(U) = sum_t r(x_t, u_t, t) is maximised over the commands U with L-BFGS-B;
its gradient comes from the adjoint pass (lambda_t = dR/dx_t, g_t = r_u + B_t^T lambda_t).
"""
import math
import time
from typing import Optional, Sequence

import numpy as np
from scipy.optimize import minimize

from lfd_controller.errors import LfdError
from lfd_controller.features import Task
from robot_common.unicycle import rollout_adjoint

COMMAND_BOUND = 1.5   # commands are bounded to 1.5 x the limits (the smooth limit gives ~96% there)
# Steps an arrival look-ahead (RecedingHorizonController min_horizon > 0) keeps beyond the arrival
# at the preferred speed (the robot accelerates and turns before it cruises).
ARRIVAL_MARGIN_STEPS = 2
# An unstall detour (RecedingHorizonController unstall > 0) lasts this many times the stall time.
ESCAPE_FACTOR = 2.5
# Below this speed (m/s; and commanding no more) the robot counts as standing (creeping) still.
STALL_SPEED = 0.08


def _static(task: Task, t: float) -> bool:
    """The task's obstacle moves slower than STALL_SPEED / 2 (m/s) at episode time t."""
    ends = np.asarray(task.obstacle_position(np.array([t, t + 1.0])), float).reshape(2, 2)
    return float(np.hypot(*(ends[1] - ends[0]))) < 0.5 * STALL_SPEED


def preferred_speed(reward, v_max: float) -> float:
    """The speed (m/s) at which a linear reward's per-step speed terms peak: the linear pull
    (goal_progress, forward_command) over twice the squared-speed penalty (speed_squared,
    speed_effort), w_lin / (2 |w_sq|) - the cruising speed of a person reward (the goal straight
    ahead) - at most v_max; v_max when the reward has no positive pull or no negative penalty (no
    speed of its own: the robot's limit). A wrapper with a `.reward` (CollisionBarrier) is looked
    through; LfdError for a reward that is not linear."""
    linear, squared = _speed_weights(reward)
    if not (linear > 0 and squared < 0):
        return float(v_max)
    return float(min(linear / (-2.0 * squared), v_max))


def _speed_weights(reward):
    """(linear, squared): a linear reward's summed weights of the per-step speed terms."""
    inner = reward
    while getattr(inner, "features", None) is None and getattr(inner, "reward", None) is not None:
        inner = inner.reward          # look through wrappers (CollisionBarrier, ArrivalReward)
    features, weights = getattr(inner, "features", None), getattr(inner, "weights", None)
    if features is None or weights is None:
        raise LfdError(f"a preferred speed needs a linear reward, got {type(inner).__name__}")
    named = dict(zip(features.names, np.asarray(weights, float)))
    return (named.get("goal_progress", 0.0) + named.get("forward_command", 0.0),
            named.get("speed_squared", 0.0) + named.get("speed_effort", 0.0))


def arrival_time_cost(reward, v_max: float) -> float:
    """The cost of one more step before arrival that makes a linear reward arrive at its own
    preferred speed v*: |w_squared| v*^2 (0 without a squared-speed penalty). Covering a distance
    D in k steps of dt costs k |w_squared| (D / k dt)^2 in speed terms (the progress sum is D
    whatever k); with c per step before arrival, k c + |w_squared| D^2 / (k dt^2) is least at
    D / (k dt) = sqrt(c / |w_squared|), which is v* for c = |w_squared| v*^2. LfdError for a
    reward that is not linear."""
    _, squared = _speed_weights(reward)
    return float(-squared * preferred_speed(reward, v_max) ** 2) if squared < 0 else 0.0


def trajectory_reward(reward, model, task: Task, start, t0: float, actions, *, gradient: bool = True,
                      terminal: float = 0.0, discount: float = 1.0):
    """R(U) and dR/dU (T, 2) for commands `actions` (T, 2) from `start` at episode time t0.

    terminal > 0 counts the last step's reward 1 + terminal times (the reward of holding the final
    state a while longer: a cost-to-go estimate for receding-horizon control); discount < 1
    weighs step t's reward discount^t (the same reward sooner is worth more)."""
    actions = np.asarray(actions, dtype=float).reshape(-1, 2)
    count = len(actions)
    times = t0 + model.dt * np.arange(1, count + 1)
    if not gradient:
        states = model.rollout(start, actions)
        values = reward.derivatives(states, actions, times, task, order=0).value
        if discount != 1.0:
            values = values * discount ** np.arange(count)
        return float(values.sum() + terminal * values[-1]), None
    if getattr(model, "rollout_partials", None) is not None:    # the unicycle's sparse path
        states, partials = model.rollout_partials(start, actions)
    else:
        states, partials = model.rollout(start, actions), None
    rd = reward.derivatives(states, actions, times, task, order=1)
    if terminal:
        scale = 1.0 + terminal
        rd.value[-1] *= scale
        rd.rx[-1] *= scale
        rd.ru[-1] *= scale
    if discount != 1.0:
        factor = discount ** np.arange(count)
        rd.value, rd.rx, rd.ru = rd.value * factor, rd.rx * factor[:, None], rd.ru * factor[:, None]
    if partials is not None:
        return float(rd.value.sum()), rollout_adjoint(model.dt, partials, rd.rx, rd.ru)
    previous = np.vstack([start, states[:-1]])
    _, a_mats, b_mats, _ = model.step_derivatives(previous, actions, second=False)
    lam = rd.rx[-1].copy()
    grad = np.empty_like(actions)
    for t in range(count - 1, -1, -1):
        if t < count - 1:
            lam = rd.rx[t] + a_mats[t + 1].T @ lam
        grad[t] = rd.ru[t] + b_mats[t].T @ lam
    return float(rd.value.sum()), grad


def command_bounds(model, count: int):
    lim = model.limits
    return [(-COMMAND_BOUND * lim.v_max, COMMAND_BOUND * lim.v_max),
            (-COMMAND_BOUND * lim.w_max, COMMAND_BOUND * lim.w_max)] * count


class _DeadlinePassed(Exception):
    """Raised inside the objective to stop L-BFGS-B at optimise_commands' deadline."""


def optimise_commands(reward, model, task: Task, start, t0: float, initial, *, max_iter: int = 200,
                      terminal: float = 0.0, discount: float = 1.0, deadline: Optional[float] = None):
    """Locally optimal commands from `initial` (T, 2); returns (commands, R). deadline: a
    time.perf_counter() time after which no further evaluation starts (the best commands
    evaluated so far are returned; the initial guess is always evaluated)."""
    initial = np.asarray(initial, dtype=float)
    shape = initial.shape
    best = [None, -np.inf]

    def negative(flat):
        if deadline is not None and best[0] is not None and time.perf_counter() > deadline:
            raise _DeadlinePassed
        value, grad = trajectory_reward(reward, model, task, start, t0, flat.reshape(shape),
                                        terminal=terminal, discount=discount)
        if value > best[1]:
            best[0], best[1] = flat.copy(), value
        return -value, -grad.reshape(-1)
    try:
        res = minimize(negative, initial.reshape(-1), jac=True, method="L-BFGS-B",
                       bounds=command_bounds(model, shape[0]),
                       options={"maxiter": max_iter, "gtol": 1e-7, "ftol": 1e-12})
    except _DeadlinePassed:
        return best[0].reshape(shape), float(best[1])
    return res.x.reshape(shape), -float(res.fun)


def seed_commands(model, count: int, turns: Sequence[float] = (0.0, 0.8, -0.8, 1.6, -1.6),
                  speed: float = 0.7) -> list:
    """Initial guesses: forward at `speed` x v_max with turn profiles a sin(pi t / T)."""
    phase = np.sin(np.pi * (np.arange(count) + 0.5) / count)
    return [np.stack([np.full(count, speed * model.limits.v_max), turn * phase], axis=1)
            for turn in turns]


def _pursuit(model, count: int, state, t0: float, aim, speed: float) -> np.ndarray:
    """Commands (count, 2) of pure pursuit at `speed` x v_max of the point aim(x, t) (slower the
    further it is off the heading, turning at twice the heading error within w_max)."""
    x, actions = np.asarray(state, float).copy(), []
    for k in range(count):
        point = aim(x, t0 + k * model.dt)
        error = np.arctan2(point[1] - x[1], point[0] - x[0]) - x[2]
        error = np.arctan2(np.sin(error), np.cos(error))
        command = np.array([speed * model.limits.v_max * max(np.cos(error), 0.0),
                            np.clip(2.0 * error, -model.limits.w_max, model.limits.w_max)])
        actions.append(command)
        x = model.step(x, command)
    return np.array(actions)


def _detour_aim(task: Task, offset: float, side: float):
    """aim(x, t) of a detour seed: the waypoint `offset` m on `side` of the obstacle (across the
    line to the goal) until the robot has passed it, then the goal."""
    goal = np.asarray(task.goal, float)
    passed = False

    def aim(x, t):
        nonlocal passed
        obstacle = np.asarray(task.obstacle_position(np.array(t)), float).reshape(2)
        to_goal = goal - x[:2]
        normal = np.array([-to_goal[1], to_goal[0]]) / max(np.linalg.norm(to_goal), 1e-9)
        waypoint = obstacle + side * offset * normal
        passed = passed or np.dot(waypoint - x[:2], to_goal) < 0.0 or \
            np.linalg.norm(waypoint - x[:2]) < 0.2
        return goal if passed else waypoint
    return aim


def detour_seeds(model, count: int, state, t0: float, task: Task, offset: float,
                 speed: float = 0.5, sides: Sequence[float] = (1.0, -1.0)) -> list:
    """Initial guesses that pass the obstacle on either side (each of `sides`, +1 left of the way
    to the goal, -1 right): pure pursuit, at `speed` x v_max, of a waypoint `offset` m beside the
    obstacle (across the line to the goal, where the obstacle is when the robot gets there), then
    of the goal. A local optimiser started from straight or turning guesses stops in front of an
    obstacle that blocks the goal; these give it both ways around (the reward still decides)."""
    return [_pursuit(model, count, state, t0, _detour_aim(task, offset, side), speed)
            for side in sides]


def goal_seed(model, count: int, state, t0: float, task: Task, speed: float) -> np.ndarray:
    """An initial guess that drives straight at the goal: pure pursuit of it at `speed` x v_max.
    The straight and turning guesses start along the robot's heading, and from a start facing
    away from the goal they settle behind a moving obstacle; heading for the goal at once is what
    a person who slips past it in front does (the reward still decides)."""
    goal = np.asarray(task.goal, float)
    return _pursuit(model, count, state, t0, lambda x, t: goal, speed)


def plan_from_seeds(reward, model, task: Task, start, t0: float, count: int, *, max_iter: int = 200,
                    seeds: Optional[list] = None):
    """The best locally optimal plan over several initial guesses: (commands, R)."""
    best = None
    for seed in seeds or seed_commands(model, count):
        plan, value = optimise_commands(reward, model, task, start, t0, seed, max_iter=max_iter)
        if best is None or value > best[1]:
            best = (plan, value)
    return best


class CollisionBarrier:
    """A reward plus a fixed (not learned) penalty for coming closer than clearance + margin to the
    obstacle's centre: -scale * ((clearance + margin - d) / margin)^2 inside, 0 outside (C1).

    Demonstrations never show what touching the obstacle costs (people keep clear of it), so a
    reward learned from them can rank a graze above a detour; the barrier encodes the physical
    fact, robot radius + obstacle radius, that the demonstrations cannot. `scale` defaults to 10 x
    the largest learned weight magnitude (the reward's own units). First-order only (planning)."""

    kind = "barrier"

    def __init__(self, reward, clearance: float, *, margin: float = 0.1, scale: Optional[float] = None):
        if not clearance > 0 or not margin > 0:
            raise LfdError(f"barrier clearance and margin must be positive, got {clearance!r}, {margin!r}")
        self.reward, self.clearance, self.margin = reward, float(clearance), float(margin)
        if scale is None:
            weights = getattr(reward, "weights", None)
            if weights is None:
                weights = np.concatenate([reward.mean_weights, reward.control_weights])
            scale = 10.0 * float(np.max(np.abs(weights)))
        self.scale = float(scale)

    def derivatives(self, states, actions, times, task: Task, *, order: int = 2):
        if order > 1:
            raise LfdError("CollisionBarrier gives first derivatives only (for planning)")
        rd = self.reward.derivatives(states, actions, times, task, order=order)
        states = np.atleast_2d(np.asarray(states, float))
        offset = states[:, :2] - np.asarray(task.obstacle_position(np.asarray(times, float)),
                                            float).reshape(-1, 2)
        distance = np.maximum(np.linalg.norm(offset, axis=1), 1e-9)
        clearance = self.clearance
        if task.obstacle_spread is not None:    # the prediction may be off by this much
            clearance = clearance + np.asarray(task.obstacle_spread(np.asarray(times, float)),
                                               float).reshape(-1)
        depth = np.maximum(clearance + self.margin - distance, 0.0) / self.margin
        rd.value = rd.value - self.scale * depth ** 2
        if order >= 1:
            rx = rd.rx.copy()
            rx[:, :2] += (2.0 * self.scale * depth / self.margin / distance)[:, None] * offset
            rd.rx = rx
        return rd


class ArrivalReward:
    """A reward with an absorbing goal region: a step in the region of `radius` m around the goal
    is worth the goal's value - the reward of resting at the goal centre (zero speed and commands,
    the step's heading and time) - instead of its own reward, so after arrival no effort, time or
    distance cost accrues (and no progress is collected). Arriving sooner is then never worse than
    crawling along the region's edge: with the goal inside the look-ahead, speed and turn costs of
    a learned reward otherwise stretch the last metres until the robot creeps, or stops, just
    outside the region.

    The region's edge is smooth (C1) so the optimiser feels it: the weight of the goal's value,
    a = smoothstep((radius + band / 2 - d) / band) at goal distance d, rises from 0 at
    radius + band / 2 to 1 at radius - band / 2; a step's reward is (1 - a) r + a r_goal. Planning
    only (first order); the goal's value is evaluated only for steps with a > 0.

    time_cost: subtracted from every step's reward before arrival (not from the goal's value):
    with a progress reward the distance made good is the same however slowly it is made, so
    without a price on time an absorbing goal removes only the costs after arrival; the
    controller uses arrival_time_cost (the price at which the reward's own trade-off arrives at
    its preferred speed)."""

    kind = "arrival"

    def __init__(self, reward, radius: float, *, band: float = 0.1, time_cost: float = 0.0):
        if not radius > 0 or not 0 < band < 2 * radius:
            raise LfdError(f"arrival radius must be positive and the band in (0, 2 x radius), got "
                           f"{radius!r}, {band!r}")
        if time_cost < 0:
            raise LfdError(f"the arrival time cost must be >= 0, got {time_cost!r}")
        self.reward, self.radius, self.band = reward, float(radius), float(band)
        self.time_cost = float(time_cost)

    def weight(self, distance):
        """(a, da/dd) for goal distances `distance` (the smoothstep of the region's edge)."""
        z = np.clip((self.radius + 0.5 * self.band - np.asarray(distance, float)) / self.band, 0.0, 1.0)
        return z * z * (3.0 - 2.0 * z), -6.0 * z * (1.0 - z) / self.band

    def derivatives(self, states, actions, times, task: Task, *, order: int = 2):
        if order > 1:
            raise LfdError("ArrivalReward gives first derivatives only (for planning)")
        states = np.atleast_2d(np.asarray(states, float))
        actions = np.atleast_2d(np.asarray(actions, float))
        count = len(states)
        times = np.broadcast_to(np.asarray(times, float), (count,))
        offset = states[:, :2] - np.asarray(task.goal, float)
        distance = np.linalg.norm(offset, axis=1)
        a, slope = self.weight(distance)
        near = np.flatnonzero(a > 0.0)
        if len(near):       # the goal's value at rest, evaluated in the same call (one call's cost)
            rest = np.zeros((len(near), 5))
            rest[:, :2] = np.asarray(task.goal, float)
            rest[:, 2] = states[near, 2]
            rd = self.reward.derivatives(np.vstack([states, rest]),
                                         np.vstack([actions, np.zeros((len(near), 2))]),
                                         np.concatenate([times, times[near]]), task, order=order)
            goal_value, rd.value = rd.value[count:], rd.value[:count]
            if order >= 1:
                goal_yaw, rd.rx, rd.ru = rd.rx[count:, 2], rd.rx[:count], rd.ru[:count]
        else:
            rd = self.reward.derivatives(states, actions, times, task, order=order)
        value = rd.value - self.time_cost if self.time_cost else rd.value.copy()
        if len(near) == 0:
            rd.value = value
            return rd
        own = value[near]
        value[near] = (1.0 - a[near]) * own + a[near] * goal_value
        rd.value = value
        if order >= 1:
            rx, ru = rd.rx.copy(), rd.ru.copy()
            rx[near] *= (1.0 - a[near])[:, None]
            rx[near, 2] += a[near] * goal_yaw          # the goal's value at the step's heading
            unit = offset[near] / np.maximum(distance[near], 1e-9)[:, None]
            rx[near, :2] += ((goal_value - own) * slope[near])[:, None] * unit
            ru[near] *= (1.0 - a[near])[:, None]
            rd.rx, rd.ru = rx, ru
        return rd


class RecedingHorizonController:
    """Re-plans `horizon` steps of the reward from the current state at every call (warm-started
    from the previous plan, shifted by the time that passed, plus turning seeds) and returns the
    first command.

    Args:
        reward: a LinearReward or GPReward; model: robot_common.unicycle.Unicycle.
        horizon: planning steps of plan_dt (None: model.dt; a coarser step looks further ahead
        for the same cost); terminal: extra weight of the last step's reward
        (holding the final state longer: a cost-to-go estimate that keeps the short horizon from
        stopping in front of an obstacle); max_iter: L-BFGS iterations for the warm start;
        seed_iter: iterations for each alternative seed (0 = no seeds after the first plan), tried
        every `seed_every` calls (turning seeds find ways around an obstacle that the warm start,
        a local optimum, misses); budget: seconds one call may take (None: no limit) - the
        iterations stop at 0.9 of it (keeping the best iterate), the seeds are skipped once half
        of it is used, and calls that still exceed it are counted in `overruns_`
        (cycle_times_ keeps every call's duration; the first call of an episode, which plans
        from every seed, is not cut);
        detour: > 0 adds two detour_seeds (pure pursuit past the obstacle this far from its
        centre on either side) to the seeds (0: none); spread_seeds: try one alternative seed per
        call, in turn, instead of all of them every seed_every calls (the same search spread
        evenly: no slow calls). Seeds are only built when they are tried; the budget stops
        trying them once half of it is used; discount < 1: step t's reward counts discount^t
        (trajectory_reward); min_horizon > 0: an arrival look-ahead - each call plans
        ceil(goal distance / (preferred_speed(reward, v_max) x step)) + ARRIVAL_MARGIN_STEPS steps,
        clipped to [min_horizon, horizon], so the plan ends about when the robot would arrive
        (with the goal well inside a fixed look-ahead, speed costs spread the last metres over it:
        a crawl; the learned windows end at arrival); 0: always `horizon` steps. `steps_` is the
        last call's count; arrival > 0: plan with ArrivalReward(reward, arrival, time_cost=
        arrival_time_cost(reward, v_max)) - an absorbing goal region of that radius (the task's
        goal tolerance): no cost accrues after arrival and each step before it costs the price at
        which the reward arrives at its preferred speed (needs a linear reward); 0: the reward as
        given; unstall > 0 (needs detour): after that many seconds standing still away from the
        goal, follow a detour seed past the obstacle for ESCAPE_FACTOR times as long, then plan
        again (`escapes_` counts them): a person who wants the goal does not wait in front of a
        static obstacle until the time runs out, and the plan's local optimum there is stable;
        stall_plans: a plan that ends standing away from the goal counts as standing (the robot
        is slowing down to stand there: `_plans_to_stop`); goal_seed > 0 adds a seed driving
        straight at the goal at this fraction of v_max (`goal_seed`; 0: none).
    """

    def __init__(self, reward, model, *, horizon: int = 20, plan_dt: Optional[float] = 0.2,
                 terminal: float = 10.0, max_iter: int = 15, seed_iter: int = 6, seed_every: int = 5,
                 seed_turns: Sequence[float] = (0.0, 1.2, -1.2), budget: Optional[float] = None,
                 detour: float = 0.0, spread_seeds: bool = False, discount: float = 1.0,
                 min_horizon: int = 0, arrival: float = 0.0, unstall: float = 0.0,
                 stall_plans: bool = False, goal_seed: float = 0.0):
        if horizon < 2:
            raise LfdError(f"the planning horizon must be at least 2 steps, got {horizon}")
        if plan_dt is not None and not plan_dt > 0:
            raise LfdError(f"the planning step must be positive, got {plan_dt}")
        self.reward, self.horizon = reward, int(horizon)
        self.model = model if plan_dt is None else type(model)(plan_dt, model.limits)
        self.max_iter, self.seed_iter, self.seed_turns = max_iter, seed_iter, seed_turns
        self.seed_every = max(1, int(seed_every))
        self.terminal = float(terminal)
        if budget is not None and not budget > 0:
            raise LfdError(f"the cycle budget must be positive seconds, got {budget!r}")
        self.budget = budget
        self.detour = float(detour)
        self.spread_seeds = bool(spread_seeds)
        if not 0.0 < discount <= 1.0:
            raise LfdError(f"the discount must be in (0, 1], got {discount!r}")
        self.discount = float(discount)
        self.min_horizon = int(min_horizon)
        if self.min_horizon != 0 and not 2 <= self.min_horizon <= self.horizon:
            raise LfdError(f"min_horizon must be 0 (fixed horizon) or in [2, horizon={self.horizon}], "
                           f"got {min_horizon!r}")
        self.speed = preferred_speed(reward, self.model.limits.v_max) if self.min_horizon else None
        if arrival < 0:
            raise LfdError(f"the arrival radius must be >= 0 (0: off), got {arrival!r}")
        self.arrival = float(arrival)
        if unstall < 0 or (unstall > 0 and self.detour <= 0):
            raise LfdError(f"unstall must be >= 0 s (0: off) and needs detour > 0, got {unstall!r}")
        self.unstall = float(unstall)
        self.stall_plans = bool(stall_plans)
        if not 0.0 <= goal_seed <= 1.0:
            raise LfdError(f"goal_seed is a fraction of v_max in [0, 1] (0: none), got {goal_seed!r}")
        self.goal_seed = float(goal_seed)
        if self.arrival > 0:
            self.reward = ArrivalReward(reward, self.arrival, time_cost=arrival_time_cost(
                reward, self.model.limits.v_max))
        self.reset()

    def reset(self) -> None:
        self.plan_: Optional[np.ndarray] = None
        self._plan_time: Optional[float] = None
        self.cycle_times_: list = []
        self.overruns_ = 0
        self.steps_ = self.horizon
        self._still_since: Optional[float] = None
        self._escape: Optional[tuple] = None       # (side, until episode time)
        self.escapes_ = 0

    def planning_steps(self, state, task: Task) -> int:
        """Steps planned from `state`: `horizon`, or with min_horizon > 0 the arrival look-ahead."""
        if not self.min_horizon:
            return self.horizon
        distance = float(np.hypot(*(np.asarray(task.goal, float) - np.asarray(state, float)[:2])))
        arrival = math.ceil(distance / (self.speed * self.model.dt)) + ARRIVAL_MARGIN_STEPS
        return int(min(max(arrival, self.min_horizon), self.horizon))

    def _warm_start(self, t: float) -> Optional[np.ndarray]:
        if self.plan_ is None or self._plan_time is None:
            return None
        steps = self.steps_
        plan = self.plan_[:steps]        # cut or held at its last command to the new length
        if len(plan) < steps:
            plan = np.vstack([plan, np.repeat(plan[-1:], steps - len(plan), axis=0)])
        shift = (t - self._plan_time) / self.model.dt
        if shift < 0 or shift >= steps - 1:
            return None
        at = np.arange(steps) + shift
        return np.column_stack([np.interp(at, np.arange(steps), plan[:, i]) for i in (0, 1)])

    def _seeds(self, state, t: float, task: Task, which: Optional[int]) -> list:
        """The alternative initial guesses (all of them, or only the one numbered `which`)."""
        detours = 2 if self.detour > 0 else 0
        count = len(self.seed_turns) + detours + (1 if self.goal_seed > 0 else 0)
        chosen = range(count) if which is None else [which % count]
        seeds = []
        for k in chosen:
            if k < len(self.seed_turns):
                seeds += seed_commands(self.model, self.steps_, (self.seed_turns[k],))
            elif k < len(self.seed_turns) + detours:
                side = (1.0, -1.0)[k - len(self.seed_turns)]
                seeds += detour_seeds(self.model, self.steps_, state, t, task, self.detour,
                                      sides=(side,))
            else:
                seeds.append(goal_seed(self.model, self.steps_, state, t, task, self.goal_seed))
        return seeds

    def _unstalled(self, state, t: float, task: Task, command: np.ndarray) -> np.ndarray:
        """With unstall > 0: after `unstall` s standing or creeping (below STALL_SPEED), or
        with stall_plans planning to (`_plans_to_stop`), away from the goal in front of a static
        obstacle (the plan keeps the robot there: a local optimum; waiting for a moving obstacle
        to pass is what a person who yields does - a blind detour then cuts in front of it),
        follow a detour seed past the obstacle - on the side away from it, or the robot faces -
        for ESCAPE_FACTOR x `unstall` s, then plan again."""
        if self._escape is not None:
            side, until = self._escape
            if t < until:
                (seed,) = detour_seeds(self.model, 2, state, t, task, self.detour,
                                       sides=(1.0 if side > 0 else -1.0,))
                return seed[0]
            self._escape, self._still_since = None, None
        reach = max(self.arrival, 0.25) * 1.5
        far = np.hypot(*(np.asarray(task.goal, float) - state[:2])) > reach
        standing = abs(state[3]) < STALL_SPEED and abs(command[0]) < STALL_SPEED
        if far and _static(task, t) and (standing or (self.stall_plans
                                                      and self._plans_to_stop(state, task, reach))):
            self._still_since = t if self._still_since is None else self._still_since
            if t - self._still_since >= self.unstall:
                obstacle = np.asarray(task.obstacle_position(np.array(t)), float).reshape(2)
                to_goal, to_obstacle = np.asarray(task.goal, float) - state[:2], obstacle - state[:2]
                cross = to_goal[0] * to_obstacle[1] - to_goal[1] * to_obstacle[0]
                heading = np.array([np.cos(state[2]), np.sin(state[2])])
                lean = to_goal[0] * heading[1] - to_goal[1] * heading[0]
                size = np.linalg.norm(to_goal) * np.linalg.norm(to_obstacle)
                side = -np.sign(cross) if abs(cross) > 0.05 * size else (np.sign(lean) or 1.0)
                self._escape = (side, t + ESCAPE_FACTOR * self.unstall)
                self.escapes_ += 1
                return self._unstalled(state, t, task, command)
        else:
            self._still_since = None
        return command

    def _plans_to_stop(self, state, task: Task, reach: float) -> bool:
        """The current plan ends at rest (below STALL_SPEED) more than `reach` m from the goal: the
        robot is slowing down to stand in front of the obstacle (a creep from 0.16 m/s down to
        STALL_SPEED took 3 s before the stall counted)."""
        if self.plan_ is None:
            return False
        end = self.planned_states(state)[-1]
        return abs(end[3]) < STALL_SPEED and np.hypot(*(np.asarray(task.goal, float) - end[:2])) > reach

    def act(self, state, t: float, task: Task, *, started: Optional[float] = None) -> np.ndarray:
        """The command to apply now at state (5,) and episode time t; `started`: the
        time.perf_counter() at which the cycle began (the budget counts from there; default now)."""
        if self.unstall > 0:
            state = np.asarray(state, float)
            return self._unstalled(state, t, task, self._act(state, t, task, started))
        return self._act(state, t, task, started)

    def _act(self, state, t: float, task: Task, started: Optional[float] = None) -> np.ndarray:
        started = time.perf_counter() if started is None else started
        self.steps_ = self.planning_steps(state, task)
        warm = self._warm_start(t)
        candidates = []
        deadline = None if self.budget is None else started + 0.9 * self.budget
        if warm is not None:
            candidates.append(optimise_commands(self.reward, self.model, task, state, t, warm,
                                                max_iter=self.max_iter, terminal=self.terminal,
                                                discount=self.discount, deadline=deadline))
            calls = len(self.cycle_times_)
            if self.spread_seeds:       # one alternative seed per call, in turn: an even cycle
                seeds_iter, which = self.seed_iter, calls
            else:                       # all of them every seed_every calls
                seeds_iter, which = (self.seed_iter if calls % self.seed_every == 0 else 0), None
        else:       # the first plan: every seed, not cut by the budget
            seeds_iter, which, deadline = self.max_iter, None, None
        if seeds_iter > 0:
            for seed in self._seeds(state, t, task, which):
                if deadline is not None and time.perf_counter() - started > 0.5 * self.budget:
                    break
                candidates.append(optimise_commands(self.reward, self.model, task, state, t, seed,
                                                    max_iter=seeds_iter, terminal=self.terminal,
                                                    discount=self.discount, deadline=deadline))
        plan, _ = max(candidates, key=lambda item: item[1])
        self.plan_, self._plan_time = plan, t
        elapsed = time.perf_counter() - started
        self.cycle_times_.append(elapsed)
        if self.budget is not None and elapsed > self.budget:
            self.overruns_ += 1
        return plan[0].copy()

    def planned_states(self, state) -> np.ndarray:
        return self.model.rollout(state, self.plan_) if self.plan_ is not None else np.empty((0, 5))
