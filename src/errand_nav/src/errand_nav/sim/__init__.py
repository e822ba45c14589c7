"""errand_nav in simulation: the people simulator's true densities as a planner's forecast (for
the demo and the benchmarks; robot_sim is a test dependency, never the planner's)."""
import numpy as np

from errand_nav.forecast import DensityForecast

__all__ = ["truth_forecast"]


def truth_forecast(sim, hours) -> DensityForecast:
    """The true densities of a robot_sim.people.PeopleSimulator at `hours` (of the simulated
    week, ascending) as a DensityForecast on its cells, its times in seconds from the week's
    start (the planners' clock in the benchmarks: hours x 3600)."""
    hours = np.atleast_1d(np.asarray(hours, float))
    cells = sim.cells
    grids = np.zeros((hours.size,) + cells.coarse.cells.shape)
    grids[:, cells.rows, cells.cols] = sim.density(hours)
    return DensityForecast(cells.coarse.origin[:2], cells.cell_size, hours * 3600.0, grids)
