"""Parameters of the lfd_controller nodes, one `NodeConfig` class per node (no ROS).

Each default is written once, here (or in the core class it names: the joystick mapping's in
`teleop.JoyMapping`, the robot limits' in `robot_common.unicycle.UnicycleLimits`). The YAML files
in config/ that the launch files load are generated from these classes
(`python -m robot_common.config_files --write`); the nodes read their `~` parameters into them
with `robot_common.ros_node.read_config`. `learn_reward` is a command-line tool: its options are
built from `LearnRewardParams` (`learn_reward_parser`).
"""
import argparse
import dataclasses
from dataclasses import dataclass, fields
from typing import Any, Dict, List, Optional, Sequence

from lfd_controller.teleop import JoyMapping
from robot_common.errors import ConfigError
from robot_common.params import NodeConfig, param
from robot_common.unicycle import UnicycleLimits

__all__ = ["JoyTeleopParams", "DemoRecorderParams", "RewardControllerParams", "LearnRewardParams",
           "learn_reward_parser", "ROS_HOME_PREFIX"]

# Leading marker of a path under $ROS_HOME (or ~/.ros), resolved by the node that uses it.
ROS_HOME_PREFIX = "$ROS_HOME"

LIMIT_NAMES = ("v_max", "w_max", "a_max", "alpha_max")


@dataclass
class JoyTeleopParams(NodeConfig):
    """joy_teleop: an Xbox 360 pad under the Linux joy driver (xpad) by default."""

    axis_linear: int = param(JoyMapping.axis_linear, "stick axis that drives (left stick up/down)")
    axis_angular: int = param(JoyMapping.axis_angular, "stick axis that turns (left stick left/right)")
    scale_linear: float = param(JoyMapping.scale_linear, "m/s at full stick")
    scale_angular: float = param(JoyMapping.scale_angular, "rad/s at full stick")
    deadzone: float = param(JoyMapping.deadzone, "stick fraction ignored around the centre, in [0, 1)")
    enable_button: int = param(JoyMapping.enable_button, "dead-man button held to move (LB)")
    record_start_button: int = param(JoyMapping.record_start_button,
                                     "starts recording a demonstration (A)")
    record_stop_button: int = param(JoyMapping.record_stop_button, "stops recording (B)")
    recorder: str = param("demo_recorder", "node whose ~start/~stop services the buttons call")

    def mapping(self) -> JoyMapping:
        """The core's joystick mapping (LfdError on a bad index or dead zone)."""
        return JoyMapping(**{spec.name: getattr(self, spec.name) for spec in fields(JoyMapping)})


@dataclass
class DemoRecorderParams(NodeConfig):
    """demo_recorder: where demonstrations go and how samples are paired."""

    bag_dir: str = param(ROS_HOME_PREFIX + "/lfd_demos",
                         "one bag per demonstration (leading $ROS_HOME: ROS_HOME or ~/.ros; "
                         "'' = no bags)")
    db_url: str = param("", "ros_mongo store URL (CouchDB or mongodb://...; '' = no database)")
    source: str = param("joystick", "who demonstrates (stored with each demo, used as a tag)")
    session_id: str = param("", "stored with each demo in the database; learn with --session-id to "
                                "take only these ('' = none)")
    min_steps: int = param(5, "shortest demonstration stored (steps)")
    use_applied_cmd: bool = param(True, "simulator: exact pairing with cmd_vel_applied + sim_time; "
                                        "robot: false (odom with the latest cmd_vel)")


@dataclass
class RewardControllerParams(NodeConfig):
    """reward_controller: receding-horizon control with a learned reward."""

    reward_file: str = param("", "reward saved by learn_reward (required)")
    rate: float = param(10.0, "control cycles per second (Hz)")
    horizon: int = param(20, "planning steps")
    plan_dt: float = param(0.2, "s per planning step (horizon * plan_dt = 4 s look-ahead)")
    terminal: float = param(10.0, "extra weight of the last step's reward (cost-to-go estimate)")
    max_iter: int = param(15, "L-BFGS iterations per cycle")
    goal_tolerance: float = param(0.25, "stops (zero command) within this distance of the goal (m)")
    v_max: float = param(UnicycleLimits.v_max, "robot speed limit (m/s; the scenario's when one is "
                                               "received)")
    w_max: float = param(UnicycleLimits.w_max, "robot turn-rate limit (rad/s)")
    a_max: float = param(UnicycleLimits.a_max, "robot acceleration limit (m/s^2)")
    alpha_max: float = param(UnicycleLimits.alpha_max, "robot angular acceleration limit (rad/s^2)")
    obstacle_radius: float = param(0.25, "radius of the obstacle seen on 'obstacle' (m)")
    robot_radius: float = param(0.18, "robot radius (m; the scenario's when one is received)")
    collision_margin: float = param(0.0, "> 0: add a fixed collision barrier this far (m) beyond "
                                         "touching the obstacle to the learned reward; 0: none")
    detour: float = param(0.0, "> 0: also try plans passing this far (m) beside the obstacle's "
                               "centre (0: none; person rewards: 0.8)")
    spread_seeds: bool = param(False, "try one alternative seed per cycle in turn instead of all "
                                      "every 5th cycle (an even cycle time; person rewards: true)")
    discount: float = param(1.0, "step t of a plan counts discount^t (< 1: the same reward sooner "
                                 "is worth more; person rewards: 0.97)")
    min_horizon: int = param(0, "> 0: plan only until about the arrival at the reward's preferred "
                                "speed, at least this many steps and at most ~horizon (the plan "
                                "ends near the goal instead of crawling into it); 0: always "
                                "~horizon steps (person rewards: 8)")
    arrival: float = param(0.0, "> 0: plan with an absorbing goal region of this radius (m; set "
                                "it to ~goal_tolerance): a step after arrival is worth resting at "
                                "the goal, no effort cost accrues there; 0: off (person rewards: "
                                "0.25)")
    unstall: float = param(0.0, "> 0 (needs ~detour): after this many seconds standing still away "
                                "from the goal, follow a detour past the obstacle for as long "
                                "(person rewards: 1.5); 0: off")
    stall_plans: bool = param(False, "with ~unstall: a plan that ends standing away from the goal "
                                     "counts as standing still (person rewards: true)")
    goal_seed: float = param(0.0, "> 0: also try a plan that drives straight at the goal at this "
                                  "fraction of ~v_max (the others start along the robot's "
                                  "heading; person rewards: 1.0); 0: none")
    obstacle_accel: float = param(0.0, "the obstacle topic is predicted at constant velocity, "
                                       "allowing for a change of velocity as hard as the "
                                       "hardest it showed in the last 2 s, and at least this "
                                       "hard (m/s^2)")
    frame: str = param("odom", "frame of the published plan")
    enabled: bool = param(True, "drive from the start (service ~enable switches)")
    lookahead: float = param(4.0, "path mode (a hallway reward): the local waypoint this far (m) "
                                  "along the path, or the furthest point up to there in the "
                                  "scan's sight")
    safety_margin: float = param(0.05, "path mode: zero command while the scan shows anything "
                                       "within this distance (m) of the robot's edge")
    blocked_after: float = param(20.0, "path mode: stood still this long (s), or without 0.3 m "
                                       "of progress along the path for 3 x as long, the path is "
                                       "reported blocked (ERROR on /diagnostics) and the robot "
                                       "stays stopped until a path another way, a goal, or a "
                                       "re-plan once it has stood blocked this long")
    replan_after: float = param(4.0, "path mode: without 0.3 m of progress this long (s), follow "
                                     "a detour planned on ~map and the scan round what blocks "
                                     "the path, the next time back up 0.3 m first (if nothing "
                                     "is behind), and so on; 0: never")
    replan_ahead: float = param(2.5, "path mode: with ~map, follow a detour at once when the "
                                     "scan shows something the map lacks (not a tracked person) "
                                     "within the detour's room of the path's next this many "
                                     "metres; 0: only when held up")
    give_way: bool = param(True, "path mode: held up by someone standing close in front (who "
                                 "may be waiting for the robot), first move aside out of their "
                                 "way and wait for them to pass")
    laser_offset: float = param(0.1, "path mode: the laser frame's distance ahead of the base (m)")
    person_radius: float = param(0.25, "path mode: radius of a tracked person (m)")
    barrier_margin: float = param(0.1, "path mode: barrier this far (m) beyond touching a person "
                                       "(a taught reward brings the person's room to people)")
    wall_margin: float = param(0.1, "path mode: barrier this far (m) beyond touching a scan "
                                    "point (walls, door frames, clutter)")
    reward_settings: bool = param(True, "drive with the controller settings saved with the reward "
                                        "(learn_reward --kind person saves horizon, plan_dt, "
                                        "terminal, detour, spread_seeds, discount, "
                                        "min_horizon, arrival, unstall, stall_plans, "
                                        "goal_seed, collision_margin; "
                                        "sim.teach_hallway saves barrier_margin) instead of "
                                        "these")

    SAVED_SETTINGS = ("horizon", "plan_dt", "terminal", "detour", "spread_seeds", "discount",
                      "min_horizon", "arrival", "unstall", "stall_plans", "goal_seed",
                      "collision_margin",
                      "barrier_margin")

    def check(self) -> None:
        if not self.rate > 0:
            raise ConfigError(f"~rate must be positive, got {self.rate!r}")
        if self.detour < 0:
            raise ConfigError(f"~detour must be >= 0, got {self.detour!r}")
        if self.collision_margin < 0:
            raise ConfigError(f"~collision_margin must be >= 0, got {self.collision_margin!r}")
        if self.obstacle_accel < 0:
            raise ConfigError(f"~obstacle_accel must be >= 0, got {self.obstacle_accel!r}")
        if not 0.0 <= self.goal_seed <= 1.0:
            raise ConfigError(f"~goal_seed must be in [0, 1] (0: none), got {self.goal_seed!r}")
        if not 0.0 < self.discount <= 1.0:
            raise ConfigError(f"~discount must be in (0, 1], got {self.discount!r}")
        if self.min_horizon != 0 and not 2 <= self.min_horizon <= self.horizon:
            raise ConfigError(f"~min_horizon must be 0 or in [2, ~horizon={self.horizon}], "
                              f"got {self.min_horizon!r}")
        if self.arrival < 0:
            raise ConfigError(f"~arrival must be >= 0 (0: off), got {self.arrival!r}")
        for name in ("lookahead", "blocked_after", "barrier_margin", "wall_margin",
                     "person_radius"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"~{name} must be positive, got {getattr(self, name)!r}")
        if self.replan_after < 0:
            raise ConfigError(f"~replan_after must be >= 0 (0: never), got {self.replan_after!r}")
        if self.replan_ahead < 0:
            raise ConfigError(f"~replan_ahead must be >= 0 (0: only when held up), got "
                              f"{self.replan_ahead!r}")
        if self.safety_margin < 0 or self.laser_offset < 0:
            raise ConfigError(f"~safety_margin and ~laser_offset must be >= 0, got "
                              f"{self.safety_margin!r}, {self.laser_offset!r}")
        if self.unstall < 0 or (self.unstall > 0 and self.detour <= 0):
            raise ConfigError(f"~unstall must be >= 0 (0: off) and needs ~detour > 0, got "
                              f"{self.unstall!r}")

    def hallway_safety(self) -> Dict[str, float]:
        """The path mode's safety settings (lfd_controller.hallway.HALLWAY_SAFETY's keys)."""
        return {"robot_radius": self.robot_radius, "person_radius": self.person_radius,
                "barrier_margin": self.barrier_margin, "wall_margin": self.wall_margin,
                "stop_margin": self.safety_margin,
                "blocked_after": self.blocked_after, "lookahead": self.lookahead,
                "replan_after": self.replan_after, "replan_ahead": self.replan_ahead,
                "give_way": self.give_way}

    def limits(self) -> UnicycleLimits:
        """The robot's limits (ModelError when one is not positive)."""
        return UnicycleLimits(**{name: getattr(self, name) for name in LIMIT_NAMES})

    def with_reward_settings(self, settings: Dict[str, Any]) -> "RewardControllerParams":
        """This configuration with the reward's saved controller settings applied (when
        ~reward_settings); ConfigError for an unknown setting or a bad value."""
        if not self.reward_settings or not settings:
            return self
        unknown = sorted(set(settings) - set(self.SAVED_SETTINGS))
        if unknown:
            raise ConfigError(f"the reward file's controller settings {unknown} are not among "
                              f"{list(self.SAVED_SETTINGS)}")
        changed = dataclasses.replace(self, **{k: type(getattr(self, k))(v) for k, v in settings.items()})
        changed.check()
        return changed

    def controller_options(self) -> Dict[str, Any]:
        """Keyword arguments of planner.RecedingHorizonController."""
        return {"horizon": self.horizon, "plan_dt": self.plan_dt, "terminal": self.terminal,
                "max_iter": self.max_iter, "detour": self.detour,
                "spread_seeds": self.spread_seeds, "discount": self.discount,
                "min_horizon": self.min_horizon, "arrival": self.arrival, "unstall": self.unstall,
                "stall_plans": self.stall_plans, "goal_seed": self.goal_seed}


@dataclass
class LearnRewardParams(NodeConfig):
    """learn_reward: where demonstrations come from, the reward model, where it goes."""

    bags: List[str] = param([], "bag files or folders of bags")
    db_url: str = param("", "ros_mongo store URL to load demonstrations from")
    scenario: str = param("", "only demonstrations of this scenario")
    session_id: str = param("", "only database demonstrations recorded with this session id")
    robot_ids: List[str] = param([], "only database demonstrations recorded by these robots (a "
                                     "fleet's central database holds every robot's); empty: all")
    kind: str = param("linear", "reward model (person: learning.fit_person_reward, for joystick "
                                "demonstrations; hallway: a path-mode reward from building drives "
                                "in bags)", choices=("linear", "gp", "person", "hallway"))
    output: str = param("", "reward file to write (YAML)")
    store_db: bool = param(False, "also store the reward in --db-url")
    plots: str = param("", "folder for plots of demos and reward field")
    seed: int = param(0, "random seed of the learner")
    trim_steps: int = param(10, "cut each demo this many steps after it first reaches the goal "
                                "(-1: no cut)")
    accept_mismatch: bool = param(False, "--kind person or hallway: save the reward even when "
                                         "its acceptance check refuses it (saved with the verdict "
                                         "and saved_anyway; default: refuse, exit 1)")

    REQUIRED = ("output",)

    def check(self) -> None:
        if not self.output:
            raise ConfigError("--output (the reward file to write) is required")

    @property
    def trim(self) -> Optional[int]:
        """Steps kept after reaching the goal; None: demonstrations are not cut."""
        return None if self.trim_steps < 0 else self.trim_steps

    @classmethod
    def from_args(cls, argv: Sequence[str]) -> "LearnRewardParams":
        """Checked options from a command line (argparse exits 2 on a malformed one)."""
        return cls.from_mapping(vars(learn_reward_parser().parse_args(list(argv))))


def learn_reward_parser() -> argparse.ArgumentParser:
    """learn_reward's command line: one --option per LearnRewardParams field (--db-url for db_url),
    with the class's defaults, descriptions and choices."""
    parser = argparse.ArgumentParser(description="Learn a reward from recorded demonstrations (CIOC).")
    for name, default, doc in LearnRewardParams.describe():
        flag = "--" + name.replace("_", "-")
        options: Dict[str, Any]
        if isinstance(default, bool):
            options = {"action": "store_true"}
        elif isinstance(default, list):
            options = {"nargs": "*", "default": default}
        else:
            options = {"type": type(default), "default": default,
                       "choices": _choices(name), "required": name in LearnRewardParams.REQUIRED}
        parser.add_argument(flag, dest=name, help=doc, **options)
    return parser


def _choices(name: str) -> Optional[Sequence[Any]]:
    spec = next(spec for spec in fields(LearnRewardParams) if spec.name == name)
    return spec.metadata.get("choices")
