"""Figures for the reports (matplotlib, Agg): unrolled maps of TD and levels, level counts."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import BoundaryNorm, ListedColormap  # noqa: E402

from . import _core  # noqa: E402


def grid_extent(grid) -> list[float]:
    """[d_min, d_max, s_min, s_max] in metres of the unrolled grid (s = arc length at r_design)."""
    r = grid.profile.radius_m
    s0 = grid.theta0_rad * r
    return [grid.d0_m, grid.d0_m + grid.n_d * grid.cell_size_m, s0, s0 + grid.n_theta * grid.cell_size_m]


def _unrolled_axes(grid, title: str):
    extent = grid_extent(grid)
    height = 7.0
    width = max(3.0, min(9.0, height * (extent[1] - extent[0]) / (extent[3] - extent[2]) * 3 + 2.5))
    fig, ax = plt.subplots(figsize=(width, height))
    ax.set_xlabel("d along the axis [m]")
    ax.set_ylabel("s along the wall from the right springline [m]")
    ax.set_title(title)
    return fig, ax, extent


def td_map(grid, path: Path, title: str = "TD (to-spray thickness)", vmax_mm: float | None = None) -> Path:
    td_mm = np.asarray(grid.td_m) * 1000.0
    fig, ax, extent = _unrolled_axes(grid, title)
    finite = td_mm[np.isfinite(td_mm)]
    vmax = vmax_mm if vmax_mm is not None else (max(50.0, float(np.nanmax(np.abs(finite)))) if finite.size else 50.0)
    im = ax.imshow(np.ma.masked_invalid(td_mm), origin="lower", extent=extent, aspect="auto",
                   cmap="RdYlBu_r", vmin=-vmax, vmax=vmax, interpolation="nearest")
    fig.colorbar(im, ax=ax, label="TD [mm] (positive: concrete missing)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


LEVEL_COLOURS = {-1: "#2c7bb6", 0: "#1a9641", 1: "#a6d96a", 2: "#ffffbf", 3: "#fdae61", 4: "#f46d43",
                 5: "#d7191c", 6: "#a50026", 7: "#67001f"}


def level_map(grid, levels, path: Path, title: str = "Priority levels") -> Path:
    lv = np.asarray(levels, dtype=float).reshape(grid.n_theta, grid.n_d)
    lv[lv == _core.NO_DATA_LEVEL] = np.nan
    lv = np.minimum(lv, 7)
    keys = sorted(LEVEL_COLOURS)
    cmap = ListedColormap([LEVEL_COLOURS[k] for k in keys])
    norm = BoundaryNorm([k - 0.5 for k in keys] + [keys[-1] + 0.5], cmap.N)
    fig, ax, extent = _unrolled_axes(grid, title)
    im = ax.imshow(np.ma.masked_invalid(lv), origin="lower", extent=extent, aspect="auto", cmap=cmap, norm=norm,
                   interpolation="nearest")
    cb = fig.colorbar(im, ax=ax, ticks=keys, label="level (0 = within +-50 mm; 7 = 7 and above)")
    cb.ax.set_yticklabels([str(k) for k in keys])
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def level_counts_chart(rounds: list[dict[int, int]], labels: list[str], path: Path) -> Path:
    """Grouped bars: cells per level for each stage (before, after round 1, ...)."""
    levels = sorted({lv for counts in rounds for lv in counts})
    fig, ax = plt.subplots(figsize=(8, 4))
    width = 0.8 / max(1, len(rounds))
    for i, (counts, label) in enumerate(zip(rounds, labels)):
        ax.bar(np.arange(len(levels)) + i * width, [counts.get(lv, 0) for lv in levels], width, label=label)
    ax.set_xticks(np.arange(len(levels)) + 0.4 - width / 2)
    ax.set_xticklabels([str(lv) for lv in levels])
    ax.set_xlabel("level")
    ax.set_ylabel("cells")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
