"""Smooth reward features for navigating to a goal around one (possibly moving) obstacle (no ROS).

The original features were the radial vectors from the robot to the goal and to the obstacle and
the angle between them. They are made smooth (softened norms, Gaussian fall-offs) so the reward
has the first and second derivatives inverse optimal control needs; exact derivatives come from
forward-mode automatic differentiation (jets.py). State features depend on (px, py, yaw) and on
the episode time through the obstacle's position; control features are the squared commands.
"""
from dataclasses import dataclass
from typing import Callable, List, Optional, Sequence

import numpy as np

from lfd_controller.errors import LfdError
from lfd_controller.jets import Jet

STATE_FEATURES = ("goal_distance", "goal_heading", "obstacle_proximity", "obstacle_ahead")
CONTROL_FEATURES = ("speed_effort", "turn_effort")
FEATURE_NAMES = STATE_FEATURES + CONTROL_FEATURES
# Optional linear control feature: the commanded forward speed. With speed_effort it gives the
# reward a preferred cruising speed (w_fwd / 2 w_effort): how people drive with a joystick, who
# hold the stick at a comfortable position rather than trading effort against summed distance.
FORWARD_FEATURE = "forward_command"
# Optional state feature: heading toward a near obstacle (people turn away from what they face,
# well before they get close), fading with distance over ahead_scale.
FACING_FEATURE = "obstacle_facing"
# Optional state feature: squared speed near the goal (people brake as they arrive and stop
# there), v^2 exp(-|goal - p|^2 / (2 goal_slow_scale^2)).
SLOWING_FEATURE = "goal_slowing"
# Optional state feature: progress toward the goal per step, v * cos(bearing to the goal) (softened
# like goal_heading). Summed over a drive it telescopes to (start - end goal distance) / dt: the
# same pull at any distance, and none once at the goal - a person's "get there", which a summed
# distance (asking for more speed the farther the goal) is not.
PROGRESS_FEATURE = "goal_progress"
# Optional state feature: the obstacle's proximity where robot and obstacle will be `predicted`
# seconds ahead (robot at its current speed and heading, obstacle along its known motion): a
# smooth time-to-collision, exp(-|p + tau v (cos, sin) - o(t + tau)|^2 / (2 proximity_scale^2)).
PREDICTED_FEATURE = "obstacle_predicted"
# Optional state features: the squared speeds of the robot, v^2 and w^2. With goal_progress (linear
# in v) they give a preferred speed on the state: at that speed the reward's gradient with respect
# to v vanishes, so the curvature of the acceleration limit (the second-order dynamics term, which
# makes a reward linear in v convex in the command where a jittery stick decelerates) drops out.
STATE_EFFORT_FEATURES = ("speed_squared", "turn_squared")


def as_trajectory(states, actions, times):
    """(states (T, 5), actions (T, 2), times (T,)) as float arrays; LfdError when their lengths
    differ."""
    states = np.atleast_2d(np.asarray(states, float))
    actions = np.atleast_2d(np.asarray(actions, float))
    times = np.atleast_1d(np.asarray(times, float))
    if not (len(states) == len(actions) == len(times)):
        raise LfdError(f"states, actions and times differ in length: {len(states)}, "
                       f"{len(actions)}, {len(times)}")
    return states, actions, times


# seconds ahead over which a constant-velocity prediction's allowance for error grows
PREDICTION_TRUST = 1.0
# how far back (s) an obstacle's changes of velocity are remembered, and over what span (s) each
# is measured (a shorter span measures noise)
ACCEL_MEMORY, ACCEL_SPAN = 2.0, 0.5


def observed_acceleration(times, velocities) -> float:
    """The hardest change of velocity (m/s^2) an obstacle showed in the last ACCEL_MEMORY s:
    times (N,) in increasing order, velocities (N, 2) as tracked then; each change measured
    over about ACCEL_SPAN s. 0 with less than ACCEL_SPAN s of history."""
    times = np.asarray(times, float)
    velocities = np.asarray(velocities, float).reshape(-1, 2)
    if len(times) < 2:
        return 0.0
    keep = times >= times[-1] - ACCEL_MEMORY
    times, velocities = times[keep], velocities[keep]
    before = np.searchsorted(times, times - ACCEL_SPAN, side="right") - 1
    valid = before >= 0
    if not np.any(valid):
        return 0.0
    span = times[valid] - times[before[valid]]
    change = np.linalg.norm(velocities[valid] - velocities[before[valid]], axis=1)
    return float(np.max(change / np.maximum(span, 1e-6)))


def proximity_name(width: float) -> str:
    """Name of the extra proximity feature of fall-off length `width` (m)."""
    return f"obstacle_proximity_{width:g}"


@dataclass
class Task:
    """Where to go and where the obstacle is at episode time t (positions (..., 2))."""

    goal: np.ndarray
    obstacle_position: Callable[[np.ndarray], np.ndarray]
    obstacle_radius: float = 0.25
    # how far the obstacle may be from obstacle_position at episode times t (m): a prediction's
    # allowance for error (None: the positions are known)
    obstacle_spread: Optional[Callable[[np.ndarray], np.ndarray]] = None

    @classmethod
    def from_scenario(cls, scenario) -> "Task":
        return cls(np.asarray(scenario.goal, float), scenario.obstacle.position,
                   scenario.obstacle.radius)

    @classmethod
    def constant_velocity(cls, goal, position, velocity, now: float,
                          radius: float = 0.25, accel: float = 0.0) -> "Task":
        """An obstacle seen at `position` moving at `velocity` at episode time `now`. accel > 0
        (m/s^2): it may speed up, slow down or turn that hard, so it may be up to accel x s^2 / 2
        from the prediction s seconds ahead - for the first PREDICTION_TRUST s; later parts of a
        plan are planned again before the robot gets there."""
        position, velocity = np.asarray(position, float), np.asarray(velocity, float)

        def predict(t):
            return position + (np.asarray(t, float)[..., None] - now) * velocity

        def spread(t):
            ahead = np.clip(np.asarray(t, float) - now, 0.0, PREDICTION_TRUST)
            return 0.5 * accel * ahead ** 2
        return cls(np.asarray(goal, float), predict, radius, spread if accel > 0 else None)

    @classmethod
    def tracked(cls, scenario, now: float, rate: float = 10.0, accel: float = 0.0) -> "Task":
        """The task as reward_controller builds it on a robot from the obstacle's odometry at
        `rate` Hz, at episode time `now`: where the obstacle is and its velocity then, kept
        constant (constant_velocity), with the allowance for the hardest change of velocity it
        showed in the last ACCEL_MEMORY s (observed_acceleration; never below `accel`)."""
        obstacle = scenario.obstacle
        seen = np.arange(max(now - ACCEL_MEMORY - ACCEL_SPAN, 0.0), now + 1e-9, 1.0 / rate)
        hardest = max(accel, observed_acceleration(seen, obstacle.velocity_at(seen)))
        return cls.constant_velocity(scenario.goal, obstacle.position(now), obstacle.velocity_at(now),
                                     now, obstacle.radius, hardest)


@dataclass
class FeatureValues:
    """Features along a trajectory: state features (T, Ks) with jac (T, Ks, 5) and hess
    (T, Ks, 5, 5); control features (T, Kc) with jac (T, Kc, 2) and hess (T, Kc, 2, 2)."""

    state: np.ndarray
    state_jac: np.ndarray
    state_hess: Optional[np.ndarray]
    control: np.ndarray
    control_jac: np.ndarray
    control_hess: np.ndarray


class FeatureSet:
    """The reward features and their derivatives along trajectories.

    Args:
        goal_softening: softening length of the goal distance (m).
        heading_softening: softening length of the goal heading's normalisation (m).
        proximity_scale: Gaussian fall-off length of the obstacle proximity (m).
        ahead_scale: fall-off length of the "obstacle between me and the goal" feature (m).
        forward_command: add the linear control feature "forward_command" (v_cmd) after the
            effort features (default off: the original six features).
        obstacle_facing: add the state feature "obstacle_facing" after the four state features
            (default off).
        goal_slowing: add the state feature "goal_slowing" (after those), whose fall-off length
            is goal_slow_scale (m) (default off).
        goal_distance: keep the state feature "goal_distance" (default on).
        goal_progress: add the state feature "goal_progress" (v cos(bearing to goal)).
        proximity_widths: extra obstacle proximities with these fall-off lengths (m), features
            "obstacle_proximity_<width>" (several widths let the learner shape the clearance
            people keep).
        predicted: seconds ahead of the "obstacle_predicted" feature (0: off).
        state_effort: add the state features "speed_squared" and "turn_squared" (v^2, w^2).
    Order of the state features: goal_distance, goal_heading, obstacle_proximity, obstacle_ahead,
    obstacle_facing, goal_slowing, goal_progress, the extra proximities, obstacle_predicted,
    speed_squared, turn_squared (those switched on).
    """

    names: Sequence[str] = FEATURE_NAMES
    state_names: Sequence[str] = STATE_FEATURES
    control_names: Sequence[str] = CONTROL_FEATURES

    def __init__(self, *, goal_softening: float = 0.2, heading_softening: float = 0.3,
                 proximity_scale: float = 0.35, ahead_scale: float = 0.8,
                 forward_command: bool = False, obstacle_facing: bool = False,
                 goal_slowing: bool = False, goal_slow_scale: float = 0.5,
                 goal_distance: bool = True, goal_progress: bool = False,
                 proximity_widths: Sequence[float] = (), predicted: float = 0.0,
                 state_effort: bool = False):
        for name, value in (("goal_softening", goal_softening), ("heading_softening", heading_softening),
                            ("proximity_scale", proximity_scale), ("ahead_scale", ahead_scale)):
            if not value > 0:
                raise LfdError(f"feature parameter {name} must be positive, got {value!r}")
        self.goal_softening = goal_softening
        self.heading_softening = heading_softening
        self.proximity_scale = proximity_scale
        self.ahead_scale = ahead_scale
        self.forward_command = bool(forward_command)
        self.obstacle_facing = bool(obstacle_facing)
        self.goal_slowing = bool(goal_slowing)
        if not goal_slow_scale > 0:
            raise LfdError(f"feature parameter goal_slow_scale must be positive, got {goal_slow_scale!r}")
        self.goal_slow_scale = float(goal_slow_scale)
        self.goal_distance = bool(goal_distance)
        self.goal_progress = bool(goal_progress)
        self.proximity_widths = tuple(float(w) for w in proximity_widths)
        self.predicted = float(predicted)
        self.state_effort = bool(state_effort)
        if any(not w > 0 for w in self.proximity_widths) or not self.predicted >= 0:
            raise LfdError(f"proximity widths must be positive and predicted >= 0 s, got "
                           f"{list(proximity_widths)!r}, {predicted!r}")
        self.state_names = (STATE_FEATURES[int(not self.goal_distance):]
                            + ((FACING_FEATURE,) if self.obstacle_facing else ())
                            + ((SLOWING_FEATURE,) if self.goal_slowing else ())
                            + ((PROGRESS_FEATURE,) if self.goal_progress else ())
                            + tuple(proximity_name(w) for w in self.proximity_widths)
                            + ((PREDICTED_FEATURE,) if self.predicted else ())
                            + (STATE_EFFORT_FEATURES if self.state_effort else ()))
        self.control_names = CONTROL_FEATURES + ((FORWARD_FEATURE,) if self.forward_command else ())
        self.names = self.state_names + self.control_names

    def get_params(self) -> dict:
        params = {"goal_softening": self.goal_softening, "heading_softening": self.heading_softening,
                  "proximity_scale": self.proximity_scale, "ahead_scale": self.ahead_scale}
        if self.forward_command:
            params["forward_command"] = True
        if self.obstacle_facing:
            params["obstacle_facing"] = True
        if self.goal_slowing:
            params.update(goal_slowing=True, goal_slow_scale=self.goal_slow_scale)
        if not self.goal_distance:
            params["goal_distance"] = False
        if self.goal_progress:
            params["goal_progress"] = True
        if self.proximity_widths:
            params["proximity_widths"] = list(self.proximity_widths)
        if self.predicted:
            params["predicted"] = self.predicted
        if self.state_effort:
            params["state_effort"] = True
        return params

    def _state_jets(self, states: np.ndarray, goal: np.ndarray, obstacles: np.ndarray,
                    predicted_obstacles: Optional[np.ndarray], hessian: bool = True) -> List[Jet]:
        variables = Jet.variables(states[:, :self._state_vars], hessian)
        px, py, yaw = variables[:3]
        gx, gy = goal[0] - px, goal[1] - py            # radial vector to the goal
        ox, oy = obstacles[:, 0] - px, obstacles[:, 1] - py   # radial vector to the obstacle
        goal_sq = gx.square() + gy.square()
        obst_sq = ox.square() + oy.square()
        cos_yaw, sin_yaw = yaw.cos(), yaw.sin()
        jets = []
        if self.goal_distance:
            soft = self.goal_softening
            jets.append((goal_sq + soft ** 2).sqrt() - soft)
        heading = (gx * cos_yaw + gy * sin_yaw) / (goal_sq + self.heading_softening ** 2).sqrt()
        proximity = (obst_sq * (-0.5 / self.proximity_scale ** 2)).exp()
        cos_between = (gx * ox + gy * oy) / ((goal_sq + 0.01) * (obst_sq + 0.01)).sqrt()
        ahead = (obst_sq * (-0.5 / self.ahead_scale ** 2)).exp() * (cos_between + 1.0) * 0.5
        jets += [heading, proximity, ahead]
        if self.obstacle_facing:
            facing = (ox * cos_yaw + oy * sin_yaw) / (obst_sq + self.heading_softening ** 2).sqrt()
            jets.append((obst_sq * (-0.5 / self.ahead_scale ** 2)).exp() * (facing + 1.0) * 0.5)
        if self.goal_slowing:
            near_goal = (goal_sq * (-0.5 / self.goal_slow_scale ** 2)).exp()
            jets.append(variables[3].square() * near_goal)
        if self.goal_progress:
            jets.append(variables[3] * heading)
        for width in self.proximity_widths:
            jets.append((obst_sq * (-0.5 / width ** 2)).exp())
        if self.predicted:
            reach = variables[3] * self.predicted
            fx = predicted_obstacles[:, 0] - px - reach * cos_yaw
            fy = predicted_obstacles[:, 1] - py - reach * sin_yaw
            jets.append(((fx.square() + fy.square()) * (-0.5 / self.proximity_scale ** 2)).exp())
        if self.state_effort:
            jets += [variables[3].square(), variables[4].square()]
        return jets

    @property
    def _state_vars(self) -> int:
        """How many leading state entries the state features depend on (px, py, yaw[, v])."""
        if self.state_effort:
            return 5
        return 4 if (self.goal_slowing or self.goal_progress or self.predicted) else 3

    def evaluate(self, states, actions, times, task: Task, *, order: int = 2) -> FeatureValues:
        """Features of states (T, 5) and actions (T, 2) at episode times (T,)."""
        states, actions, times = as_trajectory(states, actions, times)
        count = len(states)
        ahead = None
        if self.predicted:
            ahead = np.asarray(task.obstacle_position(times + self.predicted), float).reshape(count, 2)
        jets = self._state_jets(states, np.asarray(task.goal, float),
                                np.asarray(task.obstacle_position(times), float).reshape(count, 2),
                                ahead, hessian=order >= 2)
        ks = len(jets)
        state_jac = np.zeros((count, ks, 5))
        nv = self._state_vars
        state_jac[:, :, :nv] = np.stack([jet.grad for jet in jets], axis=1)
        state_hess = None
        if order >= 2:
            state_hess = np.zeros((count, ks, 5, 5))
            state_hess[:, :, :nv, :nv] = np.stack([jet.hess for jet in jets], axis=1)
        kc = len(self.control_names)
        control_jac = np.zeros((count, kc, 2))
        control_jac[:, 0, 0], control_jac[:, 1, 1] = 2.0 * actions[:, 0], 2.0 * actions[:, 1]
        control_hess = np.zeros((count, kc, 2, 2))
        control_hess[:, 0, 0, 0] = control_hess[:, 1, 1, 1] = 2.0
        control = actions ** 2
        if self.forward_command:
            control_jac[:, 2, 0] = 1.0
            control = np.column_stack([control, actions[:, 0]])
        return FeatureValues(np.stack([jet.val for jet in jets], axis=1), state_jac, state_hess,
                             control, control_jac, control_hess)

    def weighted_first_order(self, states, actions, times, task: Task, state_weights,
                             control_weights):
        """(w_s . phi + w_c . psi (T,), its gradient in the state (T, 5) and in the action (T, 2)):
        what planning needs from a linear reward, written out by hand (no jets; features whose
        weight is 0 are skipped). `evaluate` is the reference it is tested against."""
        states = np.atleast_2d(np.asarray(states, float))
        actions = np.atleast_2d(np.asarray(actions, float))
        times = np.atleast_1d(np.asarray(times, float))
        obstacles = np.asarray(task.obstacle_position(times), float).reshape(-1, 2)
        weights = dict(zip(self.state_names, np.asarray(state_weights, float)))
        value, grad = _weighted_state_features(self, weights, states, times, task, obstacles)
        control_weights = np.asarray(control_weights, float)
        value = value + (actions ** 2) @ control_weights[:2]
        ru = 2.0 * actions * control_weights[:2]
        if self.forward_command:
            value = value + control_weights[2] * actions[:, 0]
            ru[:, 0] += control_weights[2]
        return value, grad, ru


def _ratio_gradient(num, num_d, den_sq_plus, den_d):
    """(num / sqrt(q), d/d(px, py, yaw)) for q = den_sq_plus with dq = den_d (tuples of arrays)."""
    root = np.sqrt(den_sq_plus)
    ratio = num / root
    return ratio, [nd / root - 0.5 * ratio * qd / den_sq_plus for nd, qd in zip(num_d, den_d)]


def _weighted_state_features(features: "FeatureSet", weights: dict, states, times, task: Task,
                             obstacles):
    """sum_k w_k phi_k (T,) and its state gradient (T, 5), by hand (see FeatureSet._state_jets)."""
    count = len(states)
    px, py, yaw, v, w = (states[:, i] for i in range(5))
    goal = np.asarray(task.goal, float)
    gx, gy = goal[0] - px, goal[1] - py
    ox, oy = obstacles[:, 0] - px, obstacles[:, 1] - py
    goal_sq, obst_sq = gx * gx + gy * gy, ox * ox + oy * oy
    cos_yaw, sin_yaw = np.cos(yaw), np.sin(yaw)
    value = np.zeros(count)
    grad = np.zeros((count, 5))          # columns px, py, yaw, v, w

    def add(weight, phi, d_px, d_py, d_yaw=None, d_v=None, d_w=None):
        nonlocal value
        value = value + weight * phi
        for column, part in enumerate((d_px, d_py, d_yaw, d_v, d_w)):
            if part is not None:
                grad[:, column] += weight * part

    def gaussian(sq, x_part, y_part, width):
        """exp(-sq / 2 width^2) and its (px, py) gradient, sq = x_part^2 + y_part^2 (parts = c - p)."""
        g = np.exp(sq * (-0.5 / width ** 2))
        return g, g * x_part / width ** 2, g * y_part / width ** 2

    if features.goal_distance and weights["goal_distance"]:
        root = np.sqrt(goal_sq + features.goal_softening ** 2)
        add(weights["goal_distance"], root - features.goal_softening, -gx / root, -gy / root)
    need_heading = weights["goal_heading"] or (features.goal_progress and weights[PROGRESS_FEATURE])
    if need_heading:
        heading, (h_px, h_py, h_yaw) = _ratio_gradient(
            gx * cos_yaw + gy * sin_yaw, (-cos_yaw, -sin_yaw, -gx * sin_yaw + gy * cos_yaw),
            goal_sq + features.heading_softening ** 2, (-2.0 * gx, -2.0 * gy, 0.0))
        if weights["goal_heading"]:
            add(weights["goal_heading"], heading, h_px, h_py, h_yaw)
    if weights["obstacle_proximity"]:
        add(weights["obstacle_proximity"], *gaussian(obst_sq, ox, oy, features.proximity_scale))
    if weights["obstacle_ahead"]:
        near, n_px, n_py = gaussian(obst_sq, ox, oy, features.ahead_scale)
        between, (b_px, b_py) = _ratio_gradient(
            gx * ox + gy * oy, (-ox - gx, -oy - gy), (goal_sq + 0.01) * (obst_sq + 0.01),
            (-2.0 * gx * (obst_sq + 0.01) - 2.0 * ox * (goal_sq + 0.01),
             -2.0 * gy * (obst_sq + 0.01) - 2.0 * oy * (goal_sq + 0.01)))
        half = 0.5 * (between + 1.0)
        add(weights["obstacle_ahead"], near * half, n_px * half + 0.5 * near * b_px,
            n_py * half + 0.5 * near * b_py)
    if features.obstacle_facing and weights[FACING_FEATURE]:
        near, n_px, n_py = gaussian(obst_sq, ox, oy, features.ahead_scale)
        facing, (f_px, f_py, f_yaw) = _ratio_gradient(
            ox * cos_yaw + oy * sin_yaw, (-cos_yaw, -sin_yaw, -ox * sin_yaw + oy * cos_yaw),
            obst_sq + features.heading_softening ** 2, (-2.0 * ox, -2.0 * oy, 0.0))
        half = 0.5 * (facing + 1.0)
        add(weights[FACING_FEATURE], near * half, n_px * half + 0.5 * near * f_px,
            n_py * half + 0.5 * near * f_py, 0.5 * near * f_yaw)
    if features.goal_slowing and weights[SLOWING_FEATURE]:
        near, n_px, n_py = gaussian(goal_sq, gx, gy, features.goal_slow_scale)
        add(weights[SLOWING_FEATURE], v * v * near, v * v * n_px, v * v * n_py, None, 2.0 * v * near)
    if features.goal_progress and weights[PROGRESS_FEATURE]:
        add(weights[PROGRESS_FEATURE], v * heading, v * h_px, v * h_py, v * h_yaw, heading)
    for width in features.proximity_widths:
        if weights[proximity_name(width)]:
            add(weights[proximity_name(width)], *gaussian(obst_sq, ox, oy, width))
    if features.predicted and weights[PREDICTED_FEATURE]:
        tau = features.predicted
        ahead = np.asarray(task.obstacle_position(times + tau), float).reshape(count, 2)
        fx = ahead[:, 0] - px - tau * v * cos_yaw
        fy = ahead[:, 1] - py - tau * v * sin_yaw
        g = np.exp((fx * fx + fy * fy) * (-0.5 / features.proximity_scale ** 2))
        scale = -g / features.proximity_scale ** 2     # d g = scale * (fx dfx + fy dfy)
        add(weights[PREDICTED_FEATURE], g, -scale * fx, -scale * fy,
            scale * tau * v * (fx * sin_yaw - fy * cos_yaw),
            -scale * tau * (fx * cos_yaw + fy * sin_yaw))
    if features.state_effort:
        if weights["speed_squared"]:
            add(weights["speed_squared"], v * v, None, None, None, 2.0 * v)
        if weights["turn_squared"]:
            add(weights["turn_squared"], w * w, None, None, None, None, 2.0 * w)
    return value, grad
