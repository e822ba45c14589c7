"""A synthetic expert that is optimal under a known reward: ground truth for learning (no ROS).

It plans the whole demonstration (T steps) by trajectory optimisation of the true reward from
several initial guesses and keeps the best plan: a locally (usually globally) optimal example, as
CIOC assumes. Optional noise samples the commands from the Laplace approximation of the
maximum-entropy distribution, N(U*, -H^-1) (a Boltzmann-rational expert).
"""
from typing import List, Optional, Sequence

import numpy as np

from lfd_controller.demos import Demonstration
from lfd_controller.features import FeatureSet, Task
from lfd_controller.laplace import DemoDynamics
from lfd_controller.planner import plan_from_seeds
from lfd_controller.rewards import LinearReward

# The known reward of the benchmarks and the demo: drive to the goal, face it, keep well clear of
# the obstacle (more so when it stands between the robot and the goal), and save effort.
TRUE_WEIGHTS = {"goal_distance": -1.0, "goal_heading": 0.3, "obstacle_proximity": -6.0,
                "obstacle_ahead": -1.0, "speed_effort": -0.3, "turn_effort": -0.05}


def true_reward(scale: float = 1.0, features: Optional[FeatureSet] = None) -> LinearReward:
    features = features or FeatureSet()
    return LinearReward([scale * TRUE_WEIGHTS[name] for name in features.names], features)


class SyntheticExpert:
    """Demonstrations optimal under `reward` (default: the true reward).

    Args:
        steps: length T of each demonstration; max_iter: L-BFGS iterations per initial guess;
        noise: 0 for the optimal plan, 1 for a sample of the max-ent distribution's Laplace
        approximation (values in between scale its standard deviation); random_state: the noise.
    """

    def __init__(self, reward=None, *, steps: int = 50, max_iter: int = 200, noise: float = 0.0,
                 random_state=None):
        self.reward = reward or true_reward()
        self.steps, self.max_iter, self.noise = steps, max_iter, noise
        self.rng = np.random.default_rng(random_state)

    def plan(self, scenario, start, t0: float = 0.0) -> np.ndarray:
        model, task = scenario.model(), Task.from_scenario(scenario)
        return plan_from_seeds(self.reward, model, task, start, t0, self.steps, max_iter=self.max_iter)[0]

    def demonstrate(self, scenario, start, t0: float = 0.0) -> Demonstration:
        actions = self.plan(scenario, start, t0)
        if self.noise > 0:
            actions = self._perturb(scenario, start, t0, actions)
        return Demonstration(scenario, start, actions, t0, source="synthetic_expert")

    def _perturb(self, scenario, start, t0, actions) -> np.ndarray:
        dyn = DemoDynamics(scenario.model(), start, actions, t0, Task.from_scenario(scenario))
        rd = self.reward.derivatives(dyn.states, actions, dyn.times, dyn.task)
        _, hess = dyn.grad_hess(rd)
        eigval, eigvec = np.linalg.eigh(-hess)
        std = 1.0 / np.sqrt(np.maximum(eigval, 1e-3))
        sample = eigvec @ (std * self.rng.standard_normal(len(std)))
        return actions + self.noise * sample.reshape(actions.shape)

    def demonstrations(self, scenario, starts: Sequence[np.ndarray], t0: float = 0.0) -> List[Demonstration]:
        return [self.demonstrate(scenario, start, t0) for start in starts]
