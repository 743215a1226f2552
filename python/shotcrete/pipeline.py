"""The end-to-end job behind ``shotcrete demo`` and ``shotcrete plan``: scan -> surface -> report."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np

from . import _core, plots, report
from .io import write_cloud

Progress = Callable[[str, float], None]


def _levels_dict(levels) -> dict[int, int]:
    return {int(k): int(v) for k, v in _core.level_counts(levels).items()}


def run_job(cloud: _core.Cloud, config: _core.Config, out: Path, progress: Progress | None = None,
            inputs: list[Path] = ()) -> dict:
    """Run the whole chain on ``cloud`` and write report.json, report.html, figures and clouds to ``out``."""
    progress = progress or (lambda stage, fraction: None)
    out = report.prepare_out_dir(Path(out), list(inputs))
    t0 = time.perf_counter()
    progress("surface", 0.0)
    surface = _core.build_surface(cloud, config)
    timings = {k: float(v) for k, v in surface.timings_s.items()}
    progress("surface", 1.0)

    grid = surface.grid
    result: dict = {
        "cells": int(grid.valid_count()),
        "grid_shape": [int(grid.n_theta), int(grid.n_d)],
        "points_in": int(len(cloud)),
        "points_used": int(len(surface.cloud)),
        "design_radius_m": float(surface.profile.radius_m),
        "axis_fit_rms_m": float(surface.axis_fit_rms_m),
        "levels_before": _levels_dict(surface.levels),
    }
    td = np.asarray(grid.td_m)
    finite = td[np.isfinite(td)] * 1000.0
    result["td_before_mm"] = {"mean": float(finite.mean()), "min": float(finite.min()), "max": float(finite.max())}
    result["required_volume_m3"] = float(np.nansum(np.clip(td, 0, None)) * grid.cell_size_m ** 2)

    progress("report", 0.0)
    t_report = time.perf_counter()
    figures = [
        ("Unrolled TD before spraying", plots.td_map(grid, out / "figures" / "td_before.png", "TD before spraying")),
        ("Priority levels before spraying",
         plots.level_map(grid, surface.levels, out / "figures" / "levels_before.png", "Levels before spraying")),
        ("Cells per level", plots.level_counts_chart([result["levels_before"]], ["before"],
                                                       out / "figures" / "level_counts.png")),
    ]
    write_cloud(out / "surface.ply", surface.cloud, _core.point_td(surface.cloud, surface.axis, surface.profile))
    timings["report"] = time.perf_counter() - t_report
    timings["total"] = time.perf_counter() - t0
    result["timings_s"] = timings
    report.write_json(out / "report.json", result)
    report.write_html(out, result, [(cap, str(p.relative_to(out))) for cap, p in figures])
    progress("report", 1.0)
    return result
