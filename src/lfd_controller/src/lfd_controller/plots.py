"""Plots people look at: demonstrations, the learned reward field, controller trajectories."""
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from lfd_controller.features import Task


def _axes(scenario, title: str):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5.5))
    xmin, ymin, xmax, ymax = scenario.bounds
    ax.set_xlim(xmin, xmax)
    ax.set_ylim(ymin, ymax)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title)
    ax.add_patch(plt.Circle(tuple(scenario.goal), scenario.goal_tolerance, color="tab:green", alpha=0.4))
    return fig, ax, plt


def _obstacle(ax, plt, scenario, times: Sequence[float]):
    for i, t in enumerate(times):
        x, y = scenario.obstacle.position(t)
        ax.add_patch(plt.Circle((x, y), scenario.obstacle.radius, color="tab:red",
                                alpha=0.6 if i == 0 else 0.15))


def _save(fig, plt, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_demonstrations(demos, path) -> Path:
    scenario = demos[0].scenario
    fig, ax, plt = _axes(scenario, f"{len(demos)} demonstrations ({scenario.name})")
    _obstacle(ax, plt, scenario, np.linspace(0, max(d.times()[-1] for d in demos), 6))
    for demo in demos:
        xy = demo.trajectory()[:, :2]
        ax.plot(xy[:, 0], xy[:, 1], "-", lw=1.5)
        ax.plot(xy[0, 0], xy[0, 1], "ko", ms=3)
    return _save(fig, plt, path)


def plot_reward_field(reward, scenario, path, demos: Optional[Sequence] = None, t: float = 0.0) -> Path:
    """The learned state reward over the arena (robot facing the goal) at episode time t."""
    fig, ax, plt = _axes(scenario, f"learned {reward.kind} reward (t = {t:.1f} s)")
    xmin, ymin, xmax, ymax = scenario.bounds
    xs, ys = np.meshgrid(np.linspace(xmin, xmax, 90), np.linspace(ymin, ymax, 80))
    yaw = np.arctan2(scenario.goal[1] - ys, scenario.goal[0] - xs)
    states = np.column_stack([xs.ravel(), ys.ravel(), yaw.ravel(), np.zeros((xs.size, 2))])
    values = reward.state_reward(states, np.full(len(states), t), Task.from_scenario(scenario))
    mesh = ax.pcolormesh(xs, ys, values.reshape(xs.shape), shading="auto", cmap="viridis")
    fig.colorbar(mesh, ax=ax, label="reward per step")
    _obstacle(ax, plt, scenario, [t])
    for demo in demos or []:
        xy = demo.trajectory()[:, :2]
        ax.plot(xy[:, 0], xy[:, 1], "w-", lw=0.8, alpha=0.7)
    return _save(fig, plt, path)


def plot_trajectories(results, scenario, path, title: str = "controller") -> Path:
    """Closed-loop drives (with .states, .times, .success, .collided, e.g. robot_sim's
    EpisodeResult) coloured by outcome."""
    ok = sum(r.success for r in results)
    fig, ax, plt = _axes(scenario, f"{title}: {ok}/{len(results)} reached the goal without collision")
    _obstacle(ax, plt, scenario, np.linspace(0, max(r.times[-1] for r in results), 6))
    for result in results:
        colour = "tab:blue" if result.success else ("tab:red" if result.collided else "tab:orange")
        ax.plot(result.states[:, 0], result.states[:, 1], "-", color=colour, lw=1.0, alpha=0.8)
    return _save(fig, plt, path)
