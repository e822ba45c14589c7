"""Parameters of errand_server (no ROS): one `NodeConfig` class, each default written once, here
or in the core class it names (`errand.ErrandRules`, `planning.PlannerSettings`).
config/errand_server.yaml is generated from it (`python -m robot_common.config_files --write`)."""
import dataclasses
from dataclasses import dataclass

from errand_nav.errand import ErrandRules
from errand_nav.planning import PlannerSettings
from robot_common.errors import ConfigError
from robot_common.params import NodeConfig, param

__all__ = ["ErrandServerParams"]

_RULES, _PLANNER = ErrandRules(), PlannerSettings()


@dataclass
class ErrandServerParams(NodeConfig):
    """errand_server: move_base's action with crowd-aware plans for a learned controller."""

    action_ns: str = param("move_base", "namespace of the MoveBaseAction served (move_base's, so "
                                        "task executives find it where they look)")
    map_yaml: str = param("", "a map_server map file to plan on (published latched on `map`); "
                              "\"\": the `map` topic (the robot's map server)")
    map_frame: str = param("map", "frame of the map, the plans and the feedback")
    controller_frame: str = param("", "frame of the paths sent to the controller on `path` (the "
                                      "frame of its odom; \"\": map_frame)")
    base_frame: str = param("base_link", "the robot's frame (its pose: tf map_frame -> base_frame)")
    density_service: str = param("traffic_gp/predict_density", "traffic_gp's density forecast "
                                 "service (traffic_gp/PredictDensity); \"\": plan for travel "
                                 "time alone")
    recommend_service: str = param("region_recommender/recommend", "region_search's "
                                   "RecommendRegion service (~go_to_place)")
    controller_enable: str = param("reward_controller/enable", "the controller's std_srvs/SetBool "
                                   "switch: off on cancel and abort, on with a new goal")
    candidates: int = param(5, "places asked of region_search per phrase", minimum=1)
    min_confidence: float = param(0.0, "~go_to_place drives only at this confidence or more (0: "
                                       "region_search's own \"not sure\" level decides)",
                                  minimum=0.0)
    plan_hour_of_week: float = param(-1.0, "< 0: plan for the crowd of the clock's time; >= 0: "
                                           "as if the robot left at this hour of the week (0: "
                                           "Monday 00:00 UTC; for simulations that hold the "
                                           "crowd at one hour, as robot_sim's crowd_hour does)")
    forecast_step: float = param(120.0, "s between the crowd forecast's times (look-ahead grid)",
                                 minimum=1.0)
    forecast_horizon: float = param(1800.0, "s ahead the crowd forecast reaches at most "
                                            "(beyond: held)", minimum=0.0)
    switch_gain: float = param(0.1, "a newer forecast's plan replaces the current path when its "
                                    "cost is lower by this share", minimum=0.0)
    obstacle_range: float = param(3.0, "m round the robot whose laser points are marked as "
                                       "obstacles when the path is blocked", minimum=0.0)
    obstacle_radius: float = param(0.3, "m round each such point kept out of the new path",
                                   minimum=0.0)
    snap_radius: float = param(0.6, "m: a start or goal where the robot does not fit is taken at "
                                    "the nearest spot within this where it does", minimum=0.0)
    tf_timeout: float = param(5.0, "s a new goal waits for the robot's pose on tf before it is "
                                   "aborted", minimum=0.0)
    check_rate: float = param(5.0, "looks at the errand per second (feedback at the same rate)",
                              minimum=0.1)
    goal_tolerance: float = param(_RULES.goal_tolerance, "m from the goal counts as reached",
                                  minimum=0.0)
    progress_step: float = param(_RULES.progress_step, "m closer to the goal counts as progress",
                                 minimum=0.0)
    blocked_after: float = param(_RULES.blocked_after, "s without progress: the path is blocked "
                                 "and re-planned round what the laser shows", minimum=0.0)
    replan_period: float = param(_RULES.replan_period, "s between looks at a newer crowd forecast",
                                 minimum=1.0)
    max_replans: int = param(_RULES.max_replans, "blocked re-plans per goal before it is aborted",
                             minimum=0)
    cell_size: float = param(_PLANNER.cell_size, "m: the planner's search cells", minimum=0.0)
    clearance: float = param(_PLANNER.clearance, "m the robot keeps from walls", minimum=0.0)
    comfort: float = param(_PLANNER.comfort, "m: closer to a wall than this costs extra time",
                           minimum=0.0)
    wall_cost: float = param(_PLANNER.wall_cost, "... up to this many times the time spent there",
                             minimum=0.0)
    free_speed: float = param(_PLANNER.free_speed, "m/s: the controller's cruising speed in an "
                                                   "empty hall", minimum=0.0)
    jam_density: float = param(_PLANNER.jam_density, "people/m^2 where a crowd stands still "
                                                     "(Weidmann's speed-density relation)",
                               minimum=0.0)
    crowd_gamma: float = param(_PLANNER.crowd_gamma, "1/m^2: how fast speed drops with density "
                                                     "(Weidmann)", minimum=0.0)
    min_speed: float = param(_PLANNER.min_speed, "m/s: the crowd speed is never taken slower",
                             minimum=0.0)
    meet_radius: float = param(_PLANNER.meet_radius, "m: a person this close to the path counts "
                                                     "as met", minimum=0.0)
    person_cost: float = param(_PLANNER.person_cost, "s of travel time worth meeting one person "
                                                     "fewer", minimum=0.0)
    look_ahead: float = param(_PLANNER.look_ahead, "s: forecasts beyond departure + this are held",
                              minimum=0.0)

    def rules(self) -> ErrandRules:
        """The errand rules these parameters set."""
        return ErrandRules(**{f.name: getattr(self, f.name) for f in dataclasses.fields(ErrandRules)})

    def planner_settings(self) -> PlannerSettings:
        """The planner settings these parameters set."""
        return PlannerSettings(**{f.name: getattr(self, f.name)
                                  for f in dataclasses.fields(PlannerSettings)})

    def check(self) -> None:
        if self.plan_hour_of_week >= 168.0:
            raise ConfigError(f"~plan_hour_of_week must be below 168 (a week), got "
                              f"{self.plan_hour_of_week}")
        if not self.action_ns:
            raise ConfigError("~action_ns must not be empty")
