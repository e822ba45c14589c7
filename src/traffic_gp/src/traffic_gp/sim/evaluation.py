"""Quality of crowd models against the people simulator's truth and on held-out counts (no ROS).

Works for any model with `predict(x, y, t, exposure)`; a model with `predict_latent` (the GP)
is scored with its full predictive distribution, others as Poisson with their point rate.
"""
from dataclasses import replace
from pathlib import Path
from typing import Dict, Optional, Sequence, Tuple

import numpy as np
from scipy import stats

import traffic_gp.plots as plots
import traffic_gp.predictive as predictive
from robot_common.errors import ConfigError
from robot_common.maps import FREE, OCCUPIED, GridMap, load_map
from robot_sim.building import Building, building_or_map
from robot_sim.people import PeopleSimulator
from traffic_gp.observations import Observations

WEDNESDAY = 48.0


def closed_doors(building: Building) -> Building:
    """The building with every door shut: free map cells outside all halls and rooms (the doors
    in the walls) become walls, so nobody walks from a hall into a room."""
    grid = building.grid
    inside = np.zeros(grid.cells.shape, dtype=bool)
    for area in building.areas:
        (r0, c0), (r1, c1) = [grid.world_to_cell(x, y) for x, y in ((area.box[0], area.box[1]),
                                                                      (area.box[2], area.box[3]))]
        inside[max(r0, 0):r1, max(c0, 0):c1] = True
    cells = grid.cells.copy()
    cells[~inside & (cells == FREE)] = OCCUPIED
    shut = GridMap(cells, grid.resolution, grid.origin, dict(grid.meta, doors="closed"))
    return replace(building, grid=shut)


GENERATED_SPECS = {"generated": "hall", "generated-loop": "loop"}


def generated_spec(map_spec: str) -> Optional[Tuple[str, int]]:
    """(layout, seed) of a generated floor's spec `generated:SEED` (the default floor) or
    `generated-loop:SEED` (with west and north corridors; robot_sim.building), SEED 0 when
    left out; None for anything else (a map file). ConfigError when SEED is not an integer."""
    kind, _, seed = map_spec.partition(":")
    if kind not in GENERATED_SPECS:
        return None
    try:
        return GENERATED_SPECS[kind], int(seed or 0)
    except ValueError as err:
        raise ConfigError(f"bad seed {seed!r} in map {map_spec!r} (generated:SEED or "
                          f"generated-loop:SEED)") from err


def simulator_for(map_spec: str, cell_size: float = 0.5, *, doors_closed: bool = False,
                  **options) -> PeopleSimulator:
    """`generated:SEED` or `generated-loop:SEED` (a generated building, see `generated_spec`;
    `doors_closed`: `closed_doors` of it, which also shuts the loop's doorway at the main
    hall's west end) or a map_server .yaml file (halls derived)."""
    generated = generated_spec(map_spec)
    if generated is not None:
        building = building_or_map("", generated[1], generated[0])[1]
        if doors_closed:
            building = closed_doors(building)
        return PeopleSimulator.from_building(building, cell_size, **options)
    if doors_closed:
        raise ConfigError("doors_closed needs a generated building (its rooms are known)")
    if not Path(map_spec).is_file():
        raise ConfigError(f"no map file {map_spec} (use a .yaml path, generated:SEED or "
                          f"generated-loop:SEED)")
    return PeopleSimulator.from_map(load_map(map_spec), cell_size, **options)


def weekday_views(sim: PeopleSimulator, n_views: int, *, weeks: int = 2, start_week: int = 0,
                  robots: int = 3, radius: float = 4.0, hall_share: float = 0.8,
                  progress: bool = False):
    """About `n_views` views spread over the weekdays (robots work Monday to Friday) of `weeks`
    weeks from `start_week`; `hall_share` of them from hall cells, the rest from any cell."""
    per_day = int(np.ceil(n_views / (weeks * 5)))
    views = []
    for week in range(start_week, start_week + weeks):
        for day in range(5):
            views += sim.observe(per_day, robots=robots, start=(week * 7 + day) * 24.0,
                                 hours=24.0, radius=radius, hall_share=hall_share,
                                 progress=progress)
    return views[:n_views]


def day_times(step_minutes: float = 5.0, day_start: float = WEDNESDAY) -> np.ndarray:
    """Times over one day (hours since Monday 00:00), every `step_minutes`."""
    return day_start + np.arange(0.0, 24.0, step_minutes / 60.0)


def model_counts(model, sim: PeopleSimulator, times: Sequence[float]) -> np.ndarray:
    """Expected people per whole cell, shape (len(times), n_cells)."""
    cells = sim.cells
    times = np.asarray(times, float)
    x, y = np.tile(cells.x, times.size), np.tile(cells.y, times.size)
    counts = model.predict(x, y, np.repeat(times, cells.n_cells), cells.cell_area)
    return np.asarray(counts).reshape(times.size, cells.n_cells)


def rmse(pred: np.ndarray, truth: np.ndarray, mask: Optional[np.ndarray] = None) -> float:
    diff = (pred - truth) if mask is None else (pred - truth)[:, mask]
    return float(np.sqrt(np.mean(diff ** 2)))


def latent_moments(model, obs: Observations):
    """Mean and variance of the log rate at the observations (variance 0 for point models)."""
    if hasattr(model, "predict_latent"):
        return model.predict_latent(obs.x, obs.y, obs.t)
    return np.log(model.predict(obs.x, obs.y, obs.t)), np.zeros(len(obs))


def heldout(model, obs: Observations, level: float = 0.9, seed: int = 0,
            busy: Optional[np.ndarray] = None) -> Dict[str, float]:
    """Mean held-out log-likelihood per row and interval coverage (see predictive.coverage);
    with a `busy` row mask also the coverage on those rows alone (most rows are near-certain
    zeros, which any forecast covers)."""
    mean, var = latent_moments(model, obs)
    result = {"loglik": float(np.mean(predictive.log_density(obs.count, mean, var, obs.exposure)))}
    cover = predictive.coverage(obs.count, mean, var, obs.exposure, level,
                                np.random.default_rng(seed))
    result.update({f"coverage_{k}": v for k, v in cover.items()})
    if busy is not None and busy.any():
        cover = predictive.coverage(obs.count[busy], mean[busy], var[busy], obs.exposure[busy],
                                    level, np.random.default_rng(seed))
        result.update({f"coverage_{k}_busy": v for k, v in cover.items()})
    return result


def truth_in_band(model, sim: PeopleSimulator, times: Sequence[float], level: float = 0.9) -> float:
    """Share of (cell, time) whose true density lies in the model's central `level` credible
    band of the density (the model's own uncertainty about the expected count)."""
    cells, times = sim.cells, np.asarray(times, float)
    mean, var = model.predict_latent(np.tile(cells.x, times.size), np.tile(cells.y, times.size),
                                     np.repeat(times, cells.n_cells))
    z = stats.norm.ppf(0.5 + level / 2.0)
    truth = np.log(np.maximum(sim.density(times).ravel(), 1e-12))
    return float(np.mean(np.abs(truth - mean) <= z * np.sqrt(var)))


def cells_beside_main_hall(sim: PeopleSimulator, reach: float = 1.5) -> np.ndarray:
    """Mask of the cells outside every hall whose centre is within `reach` metres (straight
    line, through walls) of a main-hall cell: the rooms and corners beside the busiest hall."""
    cells, main = sim.cells, sim.layout.main
    beside = np.zeros(cells.n_cells, dtype=bool)
    if not main.any():
        return beside
    hall_x, hall_y = cells.x[main], cells.y[main]
    for i in np.nonzero(sim.layout.hall < 0)[0]:
        beside[i] = np.min(np.hypot(hall_x - cells.x[i], hall_y - cells.y[i])) <= reach
    return beside


def wall_leakage(model, sim: PeopleSimulator, times: Sequence[float],
                 reach: float = 1.5) -> Dict[str, float]:
    """How much of the busiest hall's crowd a model puts beside it, where a simulator made with
    `room_busy=0` has nobody: `leakage` = mean predicted count in the cells beside the main hall
    (`cells_beside_main_hall`) / mean true count in the main-hall cells, over `times`; also
    `leakage_max_cell` (the worst beside cell's mean over times, same denominator) and the
    predicted / true main-hall ratio (`hall_ratio`)."""
    beside, main = cells_beside_main_hall(sim, reach), sim.layout.main
    if not beside.any() or not main.any():
        raise ConfigError("the map has no main hall with cells beside it")
    pred, truth = model_counts(model, sim, times), sim.expected_count(times)
    hall_rate = float(truth[:, main].mean())
    return {"leakage": float(pred[:, beside].mean()) / hall_rate,
            "leakage_max_cell": float(pred[:, beside].mean(axis=0).max()) / hall_rate,
            "truth_beside": float(truth[:, beside].mean()) / hall_rate,
            "hall_ratio": float(pred[:, main].mean()) / hall_rate,
            "beside_cells": int(beside.sum()), "main_cells": int(main.sum())}


class TruthModel:
    """The simulator's own rates as a model (the best any model can do)."""

    def __init__(self, sim: PeopleSimulator):
        self.sim = sim

    def predict(self, x, y, t, exposure=1.0):
        index = self.sim.cells.index_at(np.asarray(x), np.asarray(y))
        t = np.broadcast_to(np.asarray(t, float), index.shape)
        rate = np.zeros(index.shape)
        ok = index >= 0
        rate[ok] = self.sim.density_at(t[ok], index[ok])
        return np.asarray(exposure) * np.maximum(rate, 1e-12)

    def predict_latent(self, x, y, t):
        """log density and zero variance (the truth is known exactly)."""
        log_rate = np.log(self.predict(x, y, t)).ravel()
        return log_rate, np.zeros_like(log_rate)


def showcase_cells(sim: PeopleSimulator) -> Dict[str, int]:
    """A main-hall cell at its busiest spot, a back-hall cell and a cell outside the halls."""
    hall, main = sim.layout.hall, sim.layout.main
    chosen = {}
    if main.any():
        idx = np.nonzero(main)[0]
        chosen["main hall"] = int(idx[np.argmax(sim.rush_weight[idx])])
    back = np.nonzero((hall >= 0) & ~main)[0]
    if back.size:
        chosen["back hall"] = int(back[back.size // 2])
    other = np.nonzero(hall < 0)[0]
    if other.size and (hall >= 0).any():      # the spot farthest from any hall (a room's centre)
        cells = sim.cells
        halls = np.nonzero(hall >= 0)[0]
        gap = [np.min(np.hypot(cells.x[halls] - cells.x[i], cells.y[halls] - cells.y[i]))
               for i in other]
        chosen["off the halls"] = int(other[int(np.argmax(gap))])
    return chosen


def report(model, sim: PeopleSimulator, out_dir, *, name: str = "crowd",
           times: Sequence[float] = (WEDNESDAY + 1.0, WEDNESDAY + 10 + 50 / 60.0),
           step_minutes: float = 5.0) -> Dict[str, dict]:
    """Plots like the original study's (maps at `times`, chosen cells over a day, model vs
    truth) into `out_dir`; returns the numbers shown (expected people per cell)."""
    out_dir = Path(out_dir)
    marks = showcase_cells(sim)
    times = [float(t) for t in times]
    pred = model_counts(model, sim, times)
    truth = sim.expected_count(times)
    maps = {plots.clock(t): {"model": pred[i], "truth": truth[i]} for i, t in enumerate(times)}
    plots.crowd_maps(sim.cells, maps, out_dir / f"{name}_maps.png", marks=marks)
    day = day_times(step_minutes, np.floor(times[0] / 24.0) * 24.0)
    day_pred, day_truth = model_counts(model, sim, day), sim.expected_count(day)
    series, bands = {}, {}
    for label, index in marks.items():
        series[label] = {"model": day_pred[:, index], "truth": day_truth[:, index]}
        if hasattr(model, "predict_latent"):
            mean, var = model.predict_latent(sim.cells.x[index], sim.cells.y[index], day)
            spread = 1.645 * np.sqrt(var)
            bands[label] = (np.exp(mean - spread) * sim.cells.cell_area,
                            np.exp(mean + spread) * sim.cells.cell_area)
    plots.cells_over_day(day, series, out_dir / f"{name}_cells_over_day.png", bands=bands)
    numbers = {}
    for i, t in enumerate(times):
        numbers[plots.clock(t)] = {label: {"model": float(pred[i, index]),
                                           "truth": float(truth[i, index])}
                                   for label, index in marks.items()}
    return numbers
