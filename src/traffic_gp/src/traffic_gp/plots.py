"""Plots of crowd predictions (matplotlib, Agg): maps at chosen times, cells over the day."""
from pathlib import Path
from typing import Dict, Optional, Sequence

import numpy as np

from robot_common.cells import CellGrid


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def clock(hours: float) -> str:
    """'Mon 10:50' style label of hours since Monday 00:00 (just '10:50' within the first day)."""
    days = ["Mon", "Tue", "Wed", "Thu", "Fri", "Sat", "Sun"]
    minutes = int(round(hours * 60.0)) % (7 * 24 * 60)
    day, rest = divmod(minutes, 24 * 60)
    text = f"{rest // 60:02d}:{rest % 60:02d}"
    return text if day == 0 else f"{days[day]} {text}"


def crowd_maps(cells: CellGrid, maps: Dict[str, Dict[str, np.ndarray]], path, *,
               title: str = "expected people per cell", marks: Optional[Dict[str, int]] = None) -> Path:
    """One row per time, one column per source ("model", "truth", ...): per-cell values.

    `maps[time_label][source]` holds one value per cell; `marks` labels cells on the maps.
    """
    plt = _pyplot()
    times = list(maps)
    sources = list(maps[times[0]])
    top = max(float(np.nanmax(v)) for row in maps.values() for v in row.values())
    aspect = cells.shape[1] / max(cells.shape[0], 1)
    fig, axes = plt.subplots(len(times), len(sources), squeeze=False,
                             figsize=(min(2.5 + 2.8 * aspect, 9.0) * len(sources), 3.0 * len(times)))
    extent = (cells.coarse.origin[0], cells.coarse.origin[0] + cells.shape[1] * cells.cell_size,
              cells.coarse.origin[1], cells.coarse.origin[1] + cells.shape[0] * cells.cell_size)
    walls = np.where(np.isnan(cells.to_image(np.zeros(cells.n_cells))), 1.0, np.nan)
    for row, label in enumerate(times):
        for col, source in enumerate(sources):
            ax = axes[row, col]
            ax.imshow(walls, origin="lower", extent=extent, cmap="Greys", vmin=0, vmax=2)
            image = ax.imshow(cells.to_image(maps[label][source]), origin="lower", extent=extent,
                              cmap="magma_r", vmin=0.0, vmax=top)
            for name, index in (marks or {}).items():
                ax.plot(cells.x[index], cells.y[index], "c+", ms=8)
                ax.annotate(name, (cells.x[index], cells.y[index]), color="c", fontsize=7)
            ax.set_title(f"{source} at {label}", fontsize=9)
            ax.set_xticks([])
            ax.set_yticks([])
    fig.colorbar(image, ax=axes, shrink=0.8, label=title)
    return _save(fig, path)


def cells_over_day(times: np.ndarray, series: Dict[str, Dict[str, np.ndarray]], path, *,
                   bands: Optional[Dict[str, Sequence[np.ndarray]]] = None,
                   ylabel: str = "expected people in the cell") -> Path:
    """One panel per cell: each source's prediction over time; `bands[cell]` = (low, high)."""
    plt = _pyplot()
    names = list(series)
    fig, axes = plt.subplots(len(names), 1, figsize=(10, 2.4 * len(names)), sharex=True,
                             squeeze=False)
    hours = np.asarray(times) - np.floor(np.min(times) / 24.0) * 24.0
    for ax, name in zip(axes[:, 0], names):
        for source, values in series[name].items():
            ax.plot(hours, values, label=source, lw=1.2 if source != "truth" else 1.8,
                    color="k" if source == "truth" else None, alpha=0.9)
        if bands and name in bands:
            low, high = bands[name]
            ax.fill_between(hours, low, high, alpha=0.2, label="model 90% band of the expectation")
        ax.set_title(name, fontsize=9)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.legend(fontsize=7, loc="upper left")
    axes[-1, 0].set_xlabel("hour of the day")
    axes[-1, 0].set_xticks(np.arange(0, 25, 2))
    return _save(fig, path)


def lines(xs: Dict[str, Sequence[float]], ys: Dict[str, Sequence[float]], path, *, xlabel: str,
          ylabel: str, title: str = "", logx: bool = False, logy: bool = False) -> Path:
    """Simple line plot of several named series (benchmarks)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    for name in ys:
        ax.plot(xs[name], ys[name], "o-", label=name)
    ax.set_xscale("log" if logx else "linear")
    ax.set_yscale("log" if logy else "linear")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    return _save(fig, path)


def bars(groups: Dict[str, Dict[str, float]], path, *, ylabel: str, title: str = "") -> Path:
    """Grouped bars: one group per outer key, one bar per inner key."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    names = list(groups)
    series = list(groups[names[0]])
    width = 0.8 / len(series)
    for i, label in enumerate(series):
        ax.bar(np.arange(len(names)) + i * width, [groups[n][label] for n in names], width,
               label=label)
    ax.set_xticks(np.arange(len(names)) + width * (len(series) - 1) / 2)
    ax.set_xticklabels(names)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    return _save(fig, path)


def _save(fig, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path
