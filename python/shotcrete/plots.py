"""Figures for the reports (matplotlib, Agg): unrolled maps of TD and levels, level counts."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import BoundaryNorm, ListedColormap  # noqa: E402

from . import _core  # noqa: E402


def save(fig, path: Path, dpi: int = 110) -> Path:
    """Lays out, writes (creating the directory) and closes a figure."""
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def grid_extent(grid) -> list[float]:
    """[d_min, d_max, s_min, s_max] in metres of the unrolled grid (s = arc length at r_design)."""
    r = grid.profile.radius_m
    s0 = grid.theta0_rad * r
    return [grid.d0_m, grid.d0_m + grid.n_d * grid.cell_size_m, s0, s0 + grid.n_theta * grid.cell_size_m]


# Where the crown and the springlines lie on the unrolled wall: theta [rad] from the right springline.
WALL_MARKS = ((0.0, "right springline"), (np.pi / 2, "crown"), (np.pi, "left springline"))


def _mark_wall(ax, grid, extent) -> None:
    """Dashed lines at the crown and springlines that fall on the map (s = theta * r_design)."""
    r = grid.profile.radius_m
    for theta, name in WALL_MARKS:
        s = theta * r
        if extent[2] - 1e-9 <= s <= extent[3] + 1e-9:
            ax.axhline(s, color="k", lw=0.8, ls="--", alpha=0.7)
            below = s > 0.5 * (extent[2] + extent[3])  # labels stay inside the map
            ax.text(extent[0], s, f" {name}", ha="left", va="top" if below else "bottom", fontsize=7,
                    bbox={"facecolor": "white", "alpha": 0.6, "edgecolor": "none", "pad": 0.5})


def _unrolled_axes(grid, title: str):
    extent = grid_extent(grid)
    height = 7.0
    width = max(3.0, min(9.0, height * (extent[1] - extent[0]) / (extent[3] - extent[2]) * 3 + 2.5))
    fig, ax = plt.subplots(figsize=(width, height))
    ax.set_xlabel("d along the axis [m]")
    ax.set_ylabel("s along the wall from the right springline [m]")
    ax.set_title(title)
    _mark_wall(ax, grid, extent)
    return fig, ax, extent


# One TD colour scale for every map of a report (before, each round, after; the 3-D view too):
# bands in mm, fine around the level-0 band (-50, 50) so residuals show on the same scale as the
# scan; beyond the outer bounds the end colours.
TD_BOUNDS_MM = (-100.0, -50.0, -20.0, -5.0, 5.0, 20.0, 50.0, 100.0, 150.0, 200.0, 300.0)


def td_colours() -> list[str]:
    """One colour per TD band: below the first bound, between bounds, above the last (hex)."""
    cmap = plt.get_cmap("RdYlBu_r")
    n = len(TD_BOUNDS_MM) + 1
    return [matplotlib.colors.to_hex(cmap((i + 0.5) / n)) for i in range(n)]


def _td_norm():
    colours = td_colours()
    cmap = ListedColormap(colours[1:-1]).with_extremes(under=colours[0], over=colours[-1])
    return cmap, BoundaryNorm(TD_BOUNDS_MM, cmap.N)


def td_map(grid, path: Path, title: str = "TD (to-spray thickness)") -> Path:
    """TD map on the report's one TD scale (TD_BOUNDS_MM)."""
    td_mm = np.asarray(grid.td_m) * 1000.0
    fig, ax, extent = _unrolled_axes(grid, title)
    cmap, norm = _td_norm()
    im = ax.imshow(np.ma.masked_invalid(td_mm), origin="lower", extent=extent, aspect="auto",
                   cmap=cmap, norm=norm, interpolation="nearest")
    fig.colorbar(im, ax=ax, extend="both", ticks=TD_BOUNDS_MM, label="TD [mm] (positive: concrete missing)")
    return save(fig, path)


# Thickness classes of the finished wall (the core's levels: -1 over-filled, 0 within, >= 1 missing).
CLASS_COLOURS = {"missing": "#d7191c", "within": "#1a9641", "over": "#74add1"}


def class_map(grid, levels, path: Path, title: str, tolerance_mm: float) -> Path:
    """Three classes per cell from its level: missing (level >= 1: TD >= tolerance), within
    (level 0), over-filled (level -1: TD < -tolerance); grey where the scan has no data."""
    lv = np.asarray(levels, dtype=float).reshape(grid.n_theta, grid.n_d)
    cls = np.full(lv.shape, np.nan)
    cls[lv == -1] = 0
    cls[lv == 0] = 1
    cls[(lv >= 1) & (lv != _core.NO_DATA_LEVEL)] = 2
    cmap = ListedColormap([CLASS_COLOURS["over"], CLASS_COLOURS["within"], CLASS_COLOURS["missing"]]).with_extremes(
        bad="#bbbbbb")
    fig, ax, extent = _unrolled_axes(grid, title)
    im = ax.imshow(np.ma.masked_invalid(cls), origin="lower", extent=extent, aspect="auto", cmap=cmap,
                   vmin=-0.5, vmax=2.5, interpolation="nearest")
    cb = fig.colorbar(im, ax=ax, ticks=[0, 1, 2])
    t = f"{tolerance_mm:.0f}"
    cb.ax.set_yticklabels([f"over-filled\n> {t} mm", f"within\n±{t} mm", f"missing\n> {t} mm"])
    return save(fig, path)


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
    cb = fig.colorbar(im, ax=ax, ticks=keys, label="level (0 = within ±50 mm; 7 = 7 and above)")
    cb.ax.set_yticklabels([str(k) for k in keys])
    return save(fig, path)


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


def td_map_flat(grid, td_flat_m, path: Path, title: str) -> Path:
    """TD map from a flat per-cell array (row * n_d + col), as the planner returns it."""

    class _View:
        pass

    view = _View()
    for name in ("profile", "theta0_rad", "d0_m", "n_d", "n_theta", "cell_size_m"):
        setattr(view, name, getattr(grid, name))
    view.td_m = np.asarray(td_flat_m).reshape(grid.n_theta, grid.n_d)
    return td_map(view, path, title)


def passes_map(grid, td_flat_m, tracks, path: Path, title: str) -> Path:
    """Pass tracks (d, s) over the TD map, coloured by nozzle speed."""
    fig, ax, extent = _unrolled_axes(grid, title)
    td = np.asarray(td_flat_m).reshape(grid.n_theta, grid.n_d) * 1000.0
    # The TD underneath in grey on the report's TD bands (the colours are the speeds').
    grey = ListedColormap(plt.get_cmap("Greys")(np.linspace(0.05, 0.6, len(TD_BOUNDS_MM) + 1)))
    ax.imshow(np.ma.masked_invalid(td), origin="lower", extent=extent, aspect="auto", cmap=grey,
              norm=BoundaryNorm(TD_BOUNDS_MM, grey.N, extend="both"), interpolation="nearest")
    if tracks:
        speeds = np.array([t[2] for t in tracks])
        norm = matplotlib.colors.Normalize(vmin=speeds.min(), vmax=max(speeds.max(), speeds.min() + 1e-3))
        cmap = plt.get_cmap("viridis")
        for d, s, v in tracks:
            ax.plot(d, s, color=cmap(norm(v)), lw=1.2)
            ax.plot(d[:1], s[:1], "o", color=cmap(norm(v)), ms=2)
        sm = matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap)
        fig.colorbar(sm, ax=ax, label="nozzle speed [m/s] (dot: pass start)")
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def speeds_chart(plan, path: Path) -> Path:
    """Speed of every pass in spraying order, one colour per round."""
    fig, ax = plt.subplots(figsize=(9, 3.5))
    start = 0
    for i, rnd in enumerate(plan.rounds):
        v = [p.speed_mps for reg in rnd.regions for p in reg.passes]
        ax.plot(range(start, start + len(v)), v, ".", ms=3, label=f"round {i + 1}")
        start += len(v)
    ax.set_xlabel("pass (spraying order)")
    ax.set_ylabel("speed [m/s] (mean where it varies)")
    ax.set_yscale("log")
    if len(plan.rounds) <= 12:
        ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def value_map(grid, values_flat, path: Path, title: str, label: str, cmap: str = "viridis",
              symmetric: bool = False) -> Path:
    """Any per-cell value (flat, row * n_d + col) on the unrolled grid, on a continuous colour scale
    (symmetric about 0 when asked); grey where NaN."""
    v = np.asarray(values_flat, dtype=float).reshape(grid.n_theta, grid.n_d)
    fig, ax, extent = _unrolled_axes(grid, title)
    finite = v[np.isfinite(v)]
    lim = float(np.percentile(np.abs(finite), 99)) if finite.size else 1.0
    kw = {"vmin": -lim, "vmax": lim} if symmetric else {}
    im = ax.imshow(np.ma.masked_invalid(v), origin="lower", extent=extent, aspect="auto", cmap=cmap,
                   interpolation="nearest", **kw)
    fig.colorbar(im, ax=ax, label=label)
    return save(fig, path)


def scatter_measured(predicted_mm, measured_mm, path: Path, factor: float | None = None) -> Path:
    """Measured vs predicted thickness per cell, with y = x and the calibrated y = factor x."""
    p, m = np.asarray(predicted_mm, float), np.asarray(measured_mm, float)
    ok = np.isfinite(p) & np.isfinite(m)
    fig, ax = plt.subplots(figsize=(6, 5.5))
    ax.scatter(p[ok], m[ok], s=3, alpha=0.4)
    top = float(max(p[ok].max(initial=1.0), m[ok].max(initial=1.0)))
    ax.plot([0, top], [0, top], "k--", lw=1, label="measured = predicted")
    if factor is not None:
        ax.plot([0, top], [0, factor * top], "r-", lw=1, label=f"calibrated: measured = {factor:.3f} x predicted")
    ax.set_xlabel("predicted (executed deposit) [mm]")
    ax.set_ylabel("measured [mm]")
    ax.legend()
    return save(fig, path)
