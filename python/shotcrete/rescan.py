"""The closed loop after spraying (docs/architecture.md §12): a finished job's executed deposit, a
synthetic after-scan of it (``after_scan``), and the re-scan (``rescan``): the after-scan registered
to the before-scan on unsprayed reference areas, the layer measured per cell along the wall normal
(M3C2), measured vs predicted, the calibrated flow factor and the corrective round planned on the
measured residual. Every number comes from the core (``_core.register_scans``, ``measure_cells``,
``calibrate_flow``, ``plan_for_arm``); this module reads the job, writes files and figures."""
from __future__ import annotations

import csv
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from . import _core, plots, report

JOB_FILES = ("report.json", "cells.csv")
# A before-scan (or synthetic bay) whose TD along the cells' rays differs from the job's by more
# than MATCH_TD_M in more than MATCH_MISS_SHARE of the cells is not the scan the job planned on
# (the core's constants: rescan_job checks the before-scan with them).
MATCH_TD_M = _core.RESCAN_MATCH_TD_M
MATCH_MISS_SHARE = _core.RESCAN_MATCH_MISS_SHARE


@dataclass
class Job:
    """A finished job (the output directory of ``shotcrete plan`` / ``demo``): its report, its grid
    rebuilt from cells.csv (TD before per cell) and the deposit it predicted per grid cell (the
    executed deposit along the trajectory; the planner's where there was no trajectory)."""
    path: Path
    report: dict
    grid: "_core.Grid"
    predicted_m: np.ndarray  # per grid cell (row * n_d + col) [m], NaN where the job had no cell
    source: str              # "executed" | "planned"


def _float(text: str) -> float:
    return float(text) if text.strip() else float("nan")


def read_job(job_dir: str | Path, config) -> Job:
    """The job in ``job_dir`` checked against ``config`` (the design radius and cell size it was
    planned with). ValueError, one line, for a missing directory or file, or another config."""
    path = Path(job_dir)
    if not path.is_dir():
        raise ValueError(f"--job {path}: no such job directory")
    for name in JOB_FILES:
        if not (path / name).is_file():
            raise ValueError(f"--job {path}: no {name} (not the output of shotcrete plan/demo)")
    try:
        rep = json.loads((path / "report.json").read_text())
        axis_d = rep["axis"]
        radius = float(rep["design_radius_m"])
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"--job {path}: report.json is not a job report ({type(exc).__name__}: {exc})") from None
    try:
        profile = _core.design_profile_from_config(config.profile)
    except ValueError as exc:
        raise ValueError(f"--job {path}: {exc}") from None
    if abs(radius - profile.radius_m) > 1e-9:
        raise ValueError(f"--job {path}: planned with design radius {radius} m, the config's design profile has "
                         f"{profile.radius_m} m (profile.design_radius_m / section_path; pass the job's config)")
    with open(path / "cells.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    missing = [c for c in ("row", "col", "theta_rad", "d_m", "td_before_mm", "deposit_planned_mm",
                           "deposit_executed_mm") if rows and c not in rows[0]]
    if not rows or missing:
        raise ValueError(f"--job {path}: cells.csv has no cells or lacks {', '.join(missing)}")
    try:
        col = {k: np.array([_float(r[k]) for r in rows]) for k in rows[0]}
    except ValueError as exc:
        raise ValueError(f"--job {path}: cells.csv holds a value that is not a number ({exc})") from None
    axis = _core.TunnelAxis.from_direction(np.asarray(axis_d["origin_m"], float), np.asarray(axis_d["direction"], float))
    grid = _core.grid_from_cells(axis, profile, config.grid.cell_size_m, col["row"].astype(int).tolist(),
                                 col["col"].astype(int).tolist(), col["theta_rad"].tolist(), col["d_m"].tolist(),
                                 (col["td_before_mm"] / 1000.0).tolist())
    executed = col["deposit_executed_mm"]
    source = "executed" if np.isfinite(executed).all() else "planned"
    dep = executed if source == "executed" else col["deposit_planned_mm"]
    predicted = np.full(len(grid), np.nan)
    predicted[col["row"].astype(int) * grid.n_d + col["col"].astype(int)] = dep / 1000.0
    return Job(path, rep, grid, predicted, source)


def after_scan(job: Job, config):
    """The synthetic bay of ``config.synth`` after the job sprayed it (``_core.make_after_scan``:
    synth.after_* errors, the context when synth.context_enabled). ValueError when the job was not
    planned on this synthetic bay (more than 10 % of its cells' TD differ from the bay's by over 20 mm)."""
    bay = _core.make_synthetic_bay(config.synth)
    g = job.grid
    valid = np.asarray(g.valid).reshape(-1)
    cells = np.flatnonzero(valid)
    td_job = np.asarray(g.td_m).reshape(-1)[cells]
    td_bay = np.array([bay.td_at(g.d_center(int(c % g.n_d)), g.theta_center(int(c // g.n_d))) for c in cells])
    miss = float(np.mean(np.abs(td_job - td_bay) > MATCH_TD_M))
    if miss > MATCH_MISS_SHARE:
        raise ValueError(f"--after {job.path}: the job was not planned on this synthetic bay ({miss:.0%} of its cells' "
                         f"TD differ by more than {MATCH_TD_M * 1000:.0f} mm; use the job's config and synth.seed)")
    return _core.make_after_scan(bay, g, np.nan_to_num(job.predicted_m, nan=0.0), config)


def write_after_truth(cloud_path: Path, job: Job, scan, config) -> tuple[Path, Path]:
    """Ground truth beside the after-scan: ``<stem>_truth.json`` (the true pose, p_before = T
    p_after; the layer's scale and errors) and ``<stem>_truth.csv`` (per job cell: true and
    predicted thickness [mm])."""
    cloud_path = Path(cloud_path)
    js = cloud_path.with_name(cloud_path.stem + "_truth.json")
    cs = cloud_path.with_name(cloud_path.stem + "_truth.csv")
    s = config.synth
    report.write_json(js, {
        "job": str(job.path.resolve()), "cloud": cloud_path.name,
        "pose_after_to_before": np.asarray(scan.pose).tolist(),
        "pose_rpy_rad": list(s.after_pose_rpy_rad), "pose_translation_m": list(s.after_pose_translation_m),
        "layer_scale": scan.layer_scale, "flow_scale": s.after_flow_scale,
        "rebound_fraction": s.after_rebound_fraction, "model_rebound_fraction": config.deposition.rebound_fraction,
        "thickness_noise": s.after_thickness_noise, "noise_length_m": s.after_noise_length_m,
        "scanner_noise_m": s.after_noise_m, "points": len(scan.cloud), "predicted_from": job.source,
        "cells_csv": cs.name})
    g = job.grid
    truth = np.asarray(scan.true_thickness_m)
    with open(cs, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["cell", "row", "col", "theta_rad", "d_m", "true_thickness_mm", "predicted_mm"])
        for c in np.flatnonzero(np.asarray(g.valid).reshape(-1)):
            r, k = int(c // g.n_d), int(c % g.n_d)
            w.writerow([int(c), r, k, round(g.theta_center(r), 6), round(g.d_center(k), 4),
                        round(float(truth[c]) * 1000, 3), round(float(job.predicted_m[c]) * 1000, 3)])
    return js, cs


def read_pose(path: str | Path) -> np.ndarray:
    """A 4 x 4 after -> before transform from JSON: a list of 4 rows, or an object with
    ``pose_after_to_before`` (as ``synth --after`` writes). ValueError otherwise."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        if isinstance(data, dict):
            data = data["pose_after_to_before"]
        T = np.asarray(data, dtype=float)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"--initial-pose {path}: not a 4x4 pose ({type(exc).__name__})") from None
    if T.shape != (4, 4) or not np.isfinite(T).all() or not np.allclose(T[3], [0, 0, 0, 1]):
        raise ValueError(f"--initial-pose {path}: not a 4x4 rigid transform")
    if not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6):
        raise ValueError(f"--initial-pose {path}: the rotation part is not orthonormal")
    return T


# The after-scan's points the corrective round plans on: within this of the measured wall (radially).
WALL_BAND_M = _core.RESCAN_WALL_BAND_M


def calibrated_config(config, factor: float):
    """A copy of ``config`` with the deposition rate scaled by the calibrated flow factor."""
    return _core.calibrated_config(config, factor)


def rotation_deg(R: np.ndarray) -> float:
    """The angle of a rotation matrix [deg], accurate near 0 (atan2 of sin and cos, not arccos)."""
    R = np.asarray(R)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return float(np.degrees(np.arctan2(np.linalg.norm(v) / 2, (np.trace(R) - 1) / 2)))


def _pose_summary(T: np.ndarray) -> dict:
    T = np.asarray(T)
    angle = rotation_deg(T[:3, :3])
    return {"matrix": T.tolist(), "rotation_deg": angle, "translation_m": T[:3, 3].tolist()}


def _stats_mm(values_m: np.ndarray) -> dict:
    v = np.asarray(values_m, float)
    v = v[np.isfinite(v)] * 1000.0
    if not len(v):
        return {"cells": 0}
    return {"cells": int(len(v)), "mean": float(v.mean()), "min": float(v.min()), "max": float(v.max()),
            "p05": float(np.percentile(v, 5)), "p95": float(np.percentile(v, 95))}


@dataclass
class RescanResult:
    """What ``rescan`` computed: ``summary`` (report.json's body) and the core's objects."""
    summary: dict
    job: Job
    registration: "_core.Registration"
    thickness: "_core.CellThickness"
    calibration: Optional["_core.Calibration"]
    correction: Optional[object]         # ArmPlan of the corrective round (or None)
    correction_surface: Optional[object]  # its surface (the after-scan's bay)
    calibrated: Optional[object]          # the calibrated config
    points: Optional[tuple] = None        # per point on request: (core (N, 3), M3C2Result)


def rescan(before, after, job: Job, config, *, mask=None, initial: Optional[np.ndarray] = None,
           correct: bool = True, per_point: int = 0,
           progress: Optional[Callable[[str, float], None]] = None) -> RescanResult:
    """The re-scan of ``job``'s bay: ``after`` (a Cloud, metres, any frame near ``before``'s)
    registered to ``before`` (the scan the job planned on, with its surroundings) on the reference
    areas of ``config.rescan.reference`` (dry: what the job left unsprayed; box; mask: within
    rescan.mask_radius_m of ``mask``), starting from ``initial`` (4 x 4, after -> before; identity by
    default); the layer per job cell (M3C2 along the cell's ray), measured vs predicted, the flow
    factor (``calibrate_flow``), and with ``correct`` the corrective round planned for the arm on the
    after-scan's bay with the calibrated deposition rate. ``per_point`` > 0: the layer also at up to
    that many of the before-scan's wall points (``_core.measure_points``; ``result.points``). ValueError / RuntimeError, one line, for
    unusable input (empty or NaN clouds, another bay, too little overlap, no reference area)."""
    progress = progress or (lambda stage, fraction: None)
    from .robot import load_robot

    T0 = np.eye(4) if initial is None else np.asarray(initial, float)
    # The one loop (register, measure, check, calibrate, correct) is the core's, as the ROS node runs it.
    robot = job_robot(job, load_robot(config)) if correct else None
    out = _core.rescan_job(job.grid, job.predicted_m, before, after, config, mask, T0, robot, progress)
    timings = {"register": out.register_s, "measure": out.measure_s}
    reg, th, cal, cmp = out.registration, out.thickness, out.calibration, out.comparison
    measured = np.asarray(th.thickness_m)
    summary = {
        "kind": "rescan", "job": str(job.path.resolve()), "predicted_from": job.source,
        "registration": {"reference": config.rescan.reference, **_pose_summary(reg.transform),
                         "rms_mm": reg.rms_m * 1000.0, "overlap": reg.overlap, "iterations": reg.iterations,
                         "target_points": reg.target_points, "source_points": reg.source_points},
        "before_td_rms_mm": out.before_td_rms_m * 1000.0, "before_td_miss_share": out.before_td_miss_share,
        "cells": job.grid.valid_count(), "cells_measured": th.measured,
        "thickness_mm": _stats_mm(measured),
        "lod95_mm": _stats_mm(th.lod95_m),
        "residual_td_mm": _stats_mm(th.residual_td_m),
        "measured_vs_predicted_mm": {"bias": cmp.bias_m * 1000.0, "rms": cmp.rms_m * 1000.0,
                                     "max_abs": cmp.max_abs_m * 1000.0, "cells": cmp.cells},
        "calibration": ({"flow_factor": cal.factor, "std_error": cal.std_error, "cells": cal.cells,
                         "rejected": cal.rejected, "residual_rms_mm": cal.residual_rms_m * 1000.0}
                        if cal is not None else {"error": out.calibration_error}),
    }
    correction, corr_surface, cal_cfg = out.correction, out.correction_surface, out.calibrated
    if correction is not None:
        timings["correction"] = out.correction_s
        summary["correction"] = correction_summary(corr_surface, correction, out.correction_config, robot)
    points = None
    if per_point > 0:
        t3 = time.perf_counter()
        if config.io.unit_scale != 1.0:  # the core scaled its own copies; these are in the input's units
            k = config.io.unit_scale
            before, after = (_core.Cloud(np.ascontiguousarray(np.asarray(c.xyz) * k)) for c in (before, after))
        after_reg = _core.transform_cloud(after, reg.transform)
        td_job = np.asarray(job.grid.td_m).reshape(-1)
        wall = np.asarray(_core.wall_points(job.grid, before, td_job, WALL_BAND_M).xyz)
        # Not within a cylinder radius of the bay's ends: the face or the lining would fill part of it.
        g, rad = job.grid, config.rescan.cylinder_radius_m
        d = (wall - np.asarray(g.axis.origin_m)) @ np.asarray(g.axis.ex)  # TunnelAxis: d along ex
        wall = wall[(d >= g.d0_m + rad) & (d <= g.d0_m + g.n_d * g.cell_size_m - rad)]
        pick = np.random.default_rng(0).choice(len(wall), min(per_point, len(wall)), replace=False)
        core = np.ascontiguousarray(wall[np.sort(pick)])
        points = (core, _core.measure_points(job.grid.axis, core, before, after_reg, config.rescan, job.grid.profile))
        timings["per_point"] = time.perf_counter() - t3
        summary["per_point"] = {"points": len(core), "thickness_mm": _stats_mm(points[1].distance_m),
                                "lod95_mm": _stats_mm(points[1].lod95_m), "file": "points.ply"}
    summary["timings_s"] = timings
    result = RescanResult(summary, job, reg, th, cal, correction, corr_surface, cal_cfg)
    result.points = points
    return result


def job_robot(job: Job, robot):
    """``robot`` where ``job`` placed its base (report.json base_placement, robot.place_base): the rig
    that sprays the correction stands where it stood for the job."""
    placed = job.report.get("base_placement") or {}
    return robot.placed_at(np.asarray(placed["position_m"], float)) if placed.get("moved") else robot


def correction_summary(surface, arm_plan, config, robot) -> dict:
    """The corrective round in brief: the core's job summary's headline figures (``robot``: the arm it was planned for)."""
    s = _core.summarise_job(surface, arm_plan, robot, config, points_in=len(surface.cloud)).to_dict()
    keys = ("status", "problems", "levels_before", "levels_after", "rounds", "passes", "residual_mm", "spray_time_s",
            "total_time_s", "required_volume_m3", "td_before_mm", "warnings", "start_posture")
    out = {k: s[k] for k in keys if k in s}
    out["deposition_peak_rate_mps"] = config.deposition.peak_rate_mps
    out["time_weight_mm2_per_s"] = config.planner.time_weight_mm2_per_s  # rescan.correction_time_weight_mm2_per_s
    out["levelling_spacing_ratio"] = config.planner.levelling_spacing_ratio  # rescan.correction_spacing_ratio
    out["edge_overrun_m"] = config.planner.edge_overrun_m  # rescan.correction_edge_overrun_m
    return out


MEASURE_COLUMNS = ("cell", "row", "col", "theta_rad", "d_m", "td_before_mm", "predicted_mm", "measured_mm",
                   "lod95_mm", "residual_td_mm", "before_points", "after_points")


def write_outputs(out: Path, result: RescanResult) -> dict:
    """cells.csv (MEASURE_COLUMNS), the figures, plan.json of the corrective round,
    report.json and report.html into ``out``; returns report.json's ``files``."""
    from .pipeline import plan_to_dict

    g, th = result.job.grid, result.thickness
    cells = np.flatnonzero(np.asarray(g.valid).reshape(-1))
    mm = lambda a: np.asarray(a, float) * 1000.0  # noqa: E731
    cols = {"td_before_mm": mm(np.asarray(g.td_m).reshape(-1)), "predicted_mm": mm(result.job.predicted_m),
            "measured_mm": mm(th.thickness_m), "lod95_mm": mm(th.lod95_m), "residual_td_mm": mm(th.residual_td_m)}
    with open(out / "cells.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(MEASURE_COLUMNS)
        for c in cells:
            r, k = int(c // g.n_d), int(c % g.n_d)
            vals = [round(float(cols[n][c]), 2) for n in ("td_before_mm", "predicted_mm", "measured_mm", "lod95_mm",
                                                          "residual_td_mm")]
            w.writerow([int(c), r, k, round(g.theta_center(r), 6), round(g.d_center(k), 4)]
                       + ["" if v != v else v for v in vals] + [int(th.before_count[c]), int(th.after_count[c])])
    figs = out / "figures"
    diff = np.asarray(th.thickness_m) - result.job.predicted_m
    figures = [
        ("summary", "Measured layer per cell (M3C2 along the wall normal, mm)",
         plots.value_map(g, mm(th.thickness_m), figs / "thickness.png", "Measured thickness", "thickness [mm]",
                         "viridis")),
        ("summary", "Measured minus predicted thickness (mm)",
         plots.value_map(g, mm(diff), figs / "measured_minus_predicted.png", "Measured - predicted",
                         "difference [mm]", "RdBu", symmetric=True)),
        ("after", "Residual TD after spraying, measured (TD before - measured layer)",
         plots.td_map_flat(g, np.asarray(th.residual_td_m), figs / "residual_measured.png", "Measured residual TD")),
        ("after", "Measured vs predicted per cell",
         plots.scatter_measured(result.job.predicted_m * 1000, mm(th.thickness_m), figs / "measured_vs_predicted.png",
                                result.calibration.factor if result.calibration is not None else None)),
    ]
    files = {"cells": "cells.csv"}
    if result.points is not None:
        from .io import write_cloud

        write_cloud(out / "points.ply", _core.Cloud(result.points[0]), np.asarray(result.points[1].distance_m))
        files["points"] = "points.ply"  # the before-scan's wall points, intensity = layer [m] (NaN: none)
    if result.correction is not None:
        (out / "plan.json").write_text(json.dumps(plan_to_dict(result.correction.plan)) + "\n")
        files["corrective_plan"] = "plan.json"
        figures.append(("correction", "Residual TD the corrective round leaves (executed, mm)",
                        plots.td_map_flat(result.correction_surface.grid, _td_after(result.correction),
                                          figs / "corrective_residual.png", "After the corrective round")))
    files["figures"] = [str(p.relative_to(out)) for _, _, p in figures]
    result.summary["files"] = files
    report.write_json(out / "report.json", result.summary)
    report.write_html(out, result.summary, [(grp, cap, str(p.relative_to(out))) for grp, cap, p in figures],
                      title="Shotcrete re-scan")
    return files


def _td_after(arm_plan) -> np.ndarray:
    ex = getattr(arm_plan, "executed", None)
    return np.asarray(ex.td_after_m if ex is not None else arm_plan.plan.td_after_m)
