#!/usr/bin/env python3
"""Path choice with and without the crowd map: a floor with two hallways between two lobbies
(the north one busy, with classroom doors; the south one quiet and 2 m longer). A robot crosses
at random weekday times; it plans the shortest path, or the cheapest path on the crowd cost map
the node would publish (maximum over now + 30 min), or on the true densities (the best case).
People met = the true expected people in the cells it passes (and their neighbours) when it
passes them, plus a Poisson draw of that. Prints the figures and writes
artifacts/bench/traffic_path.json and a plot.

  python bench/traffic_gp/traffic_path.py [--quick]
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

sys.path.insert(0, str(Path(__file__).resolve().parent))
import traffic_common as tc  # noqa: E402

import traffic_gp.costmap as costmap  # noqa: E402
import traffic_gp.plots as plots  # noqa: E402
from robot_common.cells import CellGrid  # noqa: E402
from robot_common.maps import FREE, OCCUPIED, GridMap  # noqa: E402
from robot_sim.people import HallLayout, PeopleSimulator  # noqa: E402
from traffic_gp.model import TrafficGP  # noqa: E402
from traffic_gp.observations import Observations  # noqa: E402
from traffic_gp.queries import CrowdQueries  # noqa: E402
from traffic_gp.sim.evaluation import TruthModel, weekday_views  # noqa: E402

SPEED = 1.0           # m/s
WEIGHT = 4.0          # a cell of cost 95 counts as 1 + 4 = 5 times its length


def two_hallway_floor(resolution: float = 0.1):
    """30 x 15 m: lobbies west and east, a busy north hall (3 m) and a quiet south hall (2 m)
    whose route is about 2 m longer."""
    boxes = {"west_lobby": (0.2, 0.2, 4.0, 14.8), "east_lobby": (26.0, 0.2, 29.8, 14.8),
             "north_hall": (4.0, 10.0, 26.0, 13.0), "south_hall": (4.0, 0.2, 26.0, 2.2)}
    cells = np.full((int(15 / resolution), int(30 / resolution)), OCCUPIED, np.int8)
    for x0, y0, x1, y1 in boxes.values():
        cells[int(round(y0 / resolution)):int(round(y1 / resolution)),
              int(round(x0 / resolution)):int(round(x1 / resolution))] = FREE
    grid = GridMap(cells, resolution)
    cell_grid = CellGrid.from_map(grid, 0.5)
    busy_of = {"north_hall": 1.0, "south_hall": 0.25, "west_lobby": 0.3, "east_lobby": 0.3}
    hall = np.full(cell_grid.n_cells, -1)
    busy = np.zeros(cell_grid.n_cells)
    for number, (name, (x0, y0, x1, y1)) in enumerate(boxes.items()):
        inside = (cell_grid.x >= x0) & (cell_grid.x <= x1) & (cell_grid.y >= y0) & (cell_grid.y <= y1)
        hall[inside], busy[inside] = number, busy_of[name]
    doors = np.array([[x, 13.0] for x in (8.0, 13.0, 18.0, 23.0)])
    layout = HallLayout(list(boxes), busy, hall, hall == 2, doors)
    return PeopleSimulator(cell_grid, layout, seed=11), boxes


def cell_graph(cells: CellGrid):
    """8-connected graph of free cells with edge lengths in metres."""
    index = np.full(cells.shape, -1)
    index[cells.rows, cells.cols] = np.arange(cells.n_cells)
    rows, cols, lengths = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r2, c2 = cells.rows + dr, cells.cols + dc
        ok = (r2 >= 0) & (r2 < cells.shape[0]) & (c2 >= 0) & (c2 < cells.shape[1])
        other = np.full(cells.n_cells, -1)
        other[ok] = index[r2[ok], c2[ok]]
        good = other >= 0
        rows.append(np.nonzero(good)[0])
        cols.append(other[good])
        lengths.append(np.full(good.sum(), np.hypot(dr, dc) * cells.cell_size))
    return np.concatenate(rows), np.concatenate(cols), np.concatenate(lengths)


def plan(cells, graph, start: int, goal: int, cost=None):
    """Cheapest path from start to goal; edge weight = length x (1 + WEIGHT x mean cost / 95)."""
    a, b, length = graph
    weight = length if cost is None else length * (1 + WEIGHT * (cost[a] + cost[b]) / 190.0)
    matrix = sparse.coo_matrix((weight, (a, b)), shape=(cells.n_cells,) * 2).tocsr()
    _, previous = csgraph.dijkstra(matrix, directed=False, indices=start,
                                   return_predecessors=True)
    path = [goal]
    while path[-1] != start:
        path.append(previous[path[-1]])
    return path[::-1]


def walk(sim, path, depart: float, rng):
    """(metres, expected people met, people met) along `path` leaving at `depart` (hours)."""
    cells = sim.cells
    xy = np.column_stack([cells.x[path], cells.y[path]])
    step = np.r_[0.0, np.hypot(*np.diff(xy, axis=0).T)]
    hours = depart + np.cumsum(step) / SPEED / 3600.0
    near = np.zeros(cells.n_cells, bool)
    near[path] = True
    zone = ndimage.binary_dilation(cells.to_image(near.astype(float), 0.0) > 0,
                                   np.ones((3, 3)))                   # path cells + neighbours
    zone_cells = np.nonzero(zone[cells.rows, cells.cols])[0]
    gap = np.hypot(cells.x[zone_cells, None] - xy[None, :, 0], cells.y[zone_cells, None] - xy[None, :, 1])
    when = hours[np.argmin(gap, axis=1)]               # when the robot passes closest
    expected = float(np.sum(sim.density_at(when, zone_cells)) * cells.cell_area)
    return float(step.sum()), expected, int(rng.poisson(expected))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small smoke run")
    args = parser.parse_args(argv)
    views, steps, trips = (4000, 300, 60) if args.quick else (15000, 1200, 300)
    print(f"traffic_path: {tc.machine_note()}", flush=True)
    sim, boxes = two_hallway_floor()
    train = weekday_views(sim, views, weeks=2)
    rows = Observations.from_views(sim.cells, train).compress(1 / 60.0, None)
    start = time.perf_counter()
    model = TrafficGP(n_steps=steps, progress=True).fit(rows)
    print(f"  trained on {len(train)} views in {time.perf_counter() - start:.0f} s", flush=True)
    graph = cell_graph(sim.cells)
    rng = np.random.default_rng(5)
    learned, truth = CrowdQueries(model, sim.cells), CrowdQueries(TruthModel(sim), sim.cells)
    lobby_w = np.nonzero(sim.layout.hall == 0)[0]
    lobby_e = np.nonzero(sim.layout.hall == 1)[0]
    results = {name: [] for name in ("shortest", "crowd map", "true densities")}
    rush = []
    for _ in range(trips):
        day = rng.integers(0, 5) + 7 * 3                    # a weekday after the training weeks
        depart = day * 24.0 + rng.uniform(8.0, 18.5)
        a, b = int(rng.choice(lobby_w)), int(rng.choice(lobby_e))
        rush.append(bool(sim.rush_level(depart + np.arange(0, 0.02, 0.005)).max() > 0.2))
        window = costmap.window_times(depart, 0.5, 5 / 60.0)
        costs = {"shortest": None,
                 "crowd map": costmap.cost_values(learned.densities(window).max(0), 1.0),
                 "true densities": costmap.cost_values(truth.densities(window).max(0), 1.0)}
        seed = rng.integers(1 << 30)
        for name, cost in costs.items():
            path = plan(sim.cells, graph, a, b, None if cost is None else cost.astype(float))
            north = float(np.mean(sim.layout.hall[path] == 2))
            metres, expected, met = walk(sim, path, depart, np.random.default_rng(seed))
            results[name].append((metres, expected, met, north > 0.3))
    rush = np.array(rush)
    summary = {}
    for name, rows_ in results.items():
        table = np.array(rows_, float)
        summary[name] = {"metres": float(table[:, 0].mean()), "expected_people": float(table[:, 1].mean()),
                         "people_met": float(table[:, 2].mean()),
                         "people_met_in_rushes": float(table[rush, 2].mean()) if rush.any() else None,
                         "expected_people_in_rushes": float(table[rush, 1].mean()) if rush.any() else None,
                         "north_hall_share": float(table[:, 3].mean())}
    base = summary["shortest"]["expected_people"]
    print(f"\n{trips} trips west -> east lobby at random weekday times "
          f"({int(rush.sum())} leave in a rush before the hour):")
    print(f"  {'planner':16s} {'metres':>7s} {'people met':>11s} {'(expected)':>11s} "
          f"{'in rushes':>10s} {'north hall':>10s}")
    for name, row in summary.items():
        print(f"  {name:16s} {row['metres']:7.1f} {row['people_met']:11.2f} "
              f"{row['expected_people']:11.2f} {row['expected_people_in_rushes'] or 0:10.2f} "
              f"{row['north_hall_share']:10.0%}")
    ratio = summary["crowd map"]["expected_people"] / base
    print(f"  with the crowd map the robot meets {ratio:.2f}x the people of the shortest path "
          f"for {summary['crowd map']['metres'] / summary['shortest']['metres']:.2f}x the distance")
    plots.bars({name: {"people met, all trips": row["people_met"],
                       "people met, trips in a rush": row["people_met_in_rushes"] or 0.0}
                for name, row in summary.items()}, tc.OUT / "traffic_path.png",
               ylabel="people per trip", title="path choice between two hallways")
    tc.write_json("traffic_path", {"trips": trips, "rush_trips": int(rush.sum()), "views": len(train),
                                   "steps": steps, "weight": WEIGHT, "summary": summary,
                                   "people_ratio_crowd_map_vs_shortest": ratio})
    return 0


if __name__ == "__main__":
    sys.exit(main())
