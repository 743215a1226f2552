"""The report's 3-D view (plotly, offline): the wall coloured by TD before / after spraying
(buttons switch), the nozzle's passes coloured by their planned speed, the arm's moves between
them and its base. plotly.js is written beside report.html (plotly.min.js, no CDN)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .plots import TD_BOUNDS_MM, td_colours

PLOTLY_JS = "plotly.min.js"
# Display budget: the page stays light (the wall is shown per grid cell, the paths thinned).
MAX_WALL_CELLS = 40_000
MAX_PATH_POINTS = 20_000
MAX_MOVE_POINTS = 5_000


def _td_colourscale() -> tuple[list, list[float], list[str]]:
    """A stepped colourscale over band indices 0..n-1 (the report's TD bands, plots.TD_BOUNDS_MM),
    with colourbar ticks at the band bounds."""
    colours = td_colours()
    n = len(colours)
    scale = []
    for i, c in enumerate(colours):
        scale += [[i / n, c], [(i + 1) / n, c]]
    ticks = [i + 0.5 for i in range(len(TD_BOUNDS_MM))]
    return scale, ticks, [f"{b:+.0f}" if b else "0" for b in TD_BOUNDS_MM]


def _bands(td_mm: np.ndarray) -> np.ndarray:
    out = np.digitize(td_mm, TD_BOUNDS_MM).astype(float)
    out[~np.isfinite(td_mm)] = np.nan
    return out


def _stride(n: int, budget: int) -> int:
    return max(1, int(np.ceil(n / budget)))


def wall_arrays(grid, td_before_m, td_after_m) -> dict:
    """The wall as a surface of grid cells (mean point of each cell; NaN where the scan has no data),
    thinned to MAX_WALL_CELLS: x, y, z [m] and TD before / after [mm] as (rows, cols) arrays."""
    shape = (grid.n_theta, grid.n_d)
    valid = np.asarray(grid.valid).reshape(shape)
    xyz = np.asarray(grid.mean_xyz, dtype=float).reshape(shape + (3,)).copy()
    xyz[~valid] = np.nan
    before = np.asarray(td_before_m, dtype=float).reshape(shape) * 1000.0
    after = np.asarray(td_after_m, dtype=float).reshape(shape) * 1000.0
    k = _stride(grid.n_theta * grid.n_d, MAX_WALL_CELLS)
    k = int(np.ceil(np.sqrt(k)))  # the same step along both directions
    sl = (slice(None, None, k), slice(None, None, k))
    return {"x": xyz[sl][..., 0], "y": xyz[sl][..., 1], "z": xyz[sl][..., 2], "before": before[sl], "after": after[sl]}


def pass_paths(plan, limit: int = MAX_PATH_POINTS) -> list[dict]:
    """Per round: the nozzle positions of its passes (NaN between passes) and the planned speed at
    each waypoint (Pass.speed_at), every k-th waypoint so that all rounds stay within ``limit``."""
    total = sum(len(p.positions_m) for r in plan.rounds for g in r.regions for p in g.passes)
    k = _stride(total, limit)
    out = []
    for i, rnd in enumerate(plan.rounds):
        xyz, speed = [], []
        for reg in rnd.regions:
            for p in reg.passes:
                pos = np.asarray(p.positions_m)
                idx = sorted(set(range(0, len(pos), k)) | {len(pos) - 1})
                xyz.append(pos[idx])
                speed.append([p.speed_at(j) for j in idx])
                xyz.append(np.full((1, 3), np.nan))
                speed.append([np.nan])
        if xyz:
            out.append({"round": i + 1, "kind": rnd.kind, "level": rnd.level, "xyz": np.vstack(xyz),
                        "speed": np.concatenate(speed)})
    return out


def _r(a, digits: int):
    """Rounded for the page (mm / 0.1 mm): smaller JSON, nothing a screen shows is lost."""
    return np.round(np.asarray(a, dtype=float), digits)


def figure_html(out: Path, surface, plan, td_after_m, trajectory=None, base_position_m=None,
                after_label: str = "after spraying") -> str:
    """Writes plotly.min.js into ``out`` and returns the view's <div> (it needs that script in the
    page's head). Coordinates: the job's local frame [m]."""
    import plotly.graph_objects as go
    from plotly.offline import get_plotlyjs

    (out / PLOTLY_JS).write_text(get_plotlyjs())
    grid = surface.grid
    wall = wall_arrays(grid, grid.td_m, td_after_m)
    scale, ticks, labels = _td_colourscale()
    n_bands = len(TD_BOUNDS_MM) + 1
    surface_kw = dict(colorscale=scale, cmin=-0.5, cmax=n_bands - 0.5, showscale=True,
                      colorbar=dict(title=dict(text="TD [mm]<br>(+ missing)"), tickvals=ticks, ticktext=labels,
                                    x=1.0, len=0.85))
    before_c, after_c = _bands(wall["before"]), _bands(wall["after"])
    before_mm, after_mm = _r(wall["before"], 1), _r(wall["after"], 1)
    traces = [go.Surface(x=_r(wall["x"], 3), y=_r(wall["y"], 3), z=_r(wall["z"], 3), surfacecolor=before_c,
                         customdata=before_mm, hovertemplate="TD %{customdata} mm<extra>wall</extra>",
                         name="wall", **surface_kw)]
    paths = pass_paths(plan)
    speeds = np.concatenate([p["speed"] for p in paths]) if paths else np.array([np.nan])
    v_lo, v_hi = (float(np.nanmin(speeds)), float(np.nanmax(speeds))) if np.isfinite(speeds).any() else (0.0, 1.0)
    for j, p in enumerate(paths):
        xyz = _r(p["xyz"], 3)
        traces.append(go.Scatter3d(
            x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2], mode="lines", name=f"round {p['round']} ({p['kind']}) passes",
            line=dict(width=4, color=np.nan_to_num(_r(p["speed"], 3), nan=v_lo), colorscale="Viridis",
                      cmin=v_lo, cmax=max(v_hi, v_lo + 1e-3), showscale=j == 0,
                      colorbar=dict(title=dict(text="nozzle speed<br>[m/s]"), x=1.12, len=0.85)),
            hovertemplate="%{line.color:.3f} m/s<extra>round " + str(p["round"]) + "</extra>"))
    if trajectory is not None:
        pos = np.asarray(trajectory.positions, dtype=float)
        moving = ~np.asarray(trajectory.spraying, dtype=bool)
        xyz = np.where(moving[:, None], pos, np.nan)[:: _stride(len(pos), MAX_MOVE_POINTS)]
        traces.append(go.Scatter3d(x=_r(xyz[:, 0], 3), y=_r(xyz[:, 1], 3), z=_r(xyz[:, 2], 3), mode="lines",
                                   name="nozzle moving, not spraying", line=dict(width=2, color="#888888"),
                                   visible="legendonly", hoverinfo="skip"))
    if base_position_m is not None and np.all(np.isfinite(base_position_m)):
        b = np.asarray(base_position_m, dtype=float)
        traces.append(go.Scatter3d(x=[b[0]], y=[b[1]], z=[b[2]], mode="markers", name="arm base",
                                   marker=dict(size=6, color="black", symbol="diamond")))
    buttons = [dict(label="TD before spraying", method="restyle",
                    args=[{"surfacecolor": [before_c], "customdata": [before_mm]}, [0]]),
               dict(label=f"TD {after_label}", method="restyle",
                    args=[{"surfacecolor": [after_c], "customdata": [after_mm]}, [0]])]
    # The box around the wall, the passes and the base (not the moves: the arm's start pose may lie
    # far off), so the wall fills the view.
    pts = [np.column_stack([wall[c].ravel() for c in "xyz"])] + [p["xyz"] for p in paths]
    if base_position_m is not None and np.all(np.isfinite(base_position_m)):
        pts.append(np.asarray(base_position_m, dtype=float).reshape(1, 3))
    pts = np.vstack(pts)
    lo, hi = np.nanmin(pts, axis=0) - 0.2, np.nanmax(pts, axis=0) + 0.2
    fig = go.Figure(traces)
    fig.update_layout(
        height=620, margin=dict(l=0, r=0, t=40, b=0), legend=dict(x=0.0, y=0.0, bgcolor="rgba(255,255,255,0.7)"),
        updatemenus=[dict(type="buttons", direction="right", x=0.0, y=1.08, xanchor="left", buttons=buttons,
                          showactive=True, active=0)],
        scene=dict(aspectmode="manual", aspectratio=dict(zip("xyz", (hi - lo) / (hi - lo).max())), xaxis=dict(title="x [m] (along the axis)", range=[lo[0], hi[0]]),
                   yaxis=dict(title="y [m]", range=[lo[1], hi[1]]), zaxis=dict(title="z [m]", range=[lo[2], hi[2]]),
                   camera=dict(eye=dict(x=-1.1, y=-0.7, z=0.35), up=dict(x=0, y=0, z=1))))
    return fig.to_html(full_html=False, include_plotlyjs=False, div_id="view3d",
                       config={"displaylogo": False, "responsive": True})
