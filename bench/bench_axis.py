"""Axis estimation on transformed synthetic bays (issue 16): the default bay turned about the
vertical, graded and moved (up to survey coordinates), planned with the alignment given and with it
estimated (profile.estimate_axis, with and without the surveyed origin). Per case: the required
volume against the untransformed bay's, the mean TD of the points against the known axis's, the
worst per-point TD error, the direction error, and the fit's RMS, arc and points.

Target (issue 16): required volume within 1 % of the untransformed bay, with the alignment given
and with it estimated, measured on the bay's own cells (each cell's TD re-measured from the job's
axis): the job's own grid adds or drops partly covered end columns, which changes the required
volume by a few per cent even with the known axis (mode given_origin_1cm_along shows it; see
docs/architecture.md §3). The surface stage runs in the local frame the CLI uses (shotcrete.survey).

Whole scenes (`scene_cases`): the generator's scene around the same bay (lined previous bay,
invert, face, a 1.2 m ventilation duct 0.3 m under the crown, the rig's carrier), as generated and
turned 30 deg on a 5 % grade, with the axis known and estimated. Per case: direction error, mean and
worst TD error of the grid's cells (each cell's TD against its mean point's TD from the known axis),
the required volume against the bay alone's (known axis; the issue's target: within 1 %), and the
fit's RMS, arc, points and inlier share (the share of the scene's points the axis rests on).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import shotcrete
from shotcrete import _core
from shotcrete.survey import LocalFrame

# (name, yaw about the vertical [deg], grade [rise/run], offset [m])
PLACEMENTS = [
    ("turned 30 deg, 5 % grade", 30.0, 0.05, (3.0, -2.0, 1.0)),
    ("turned -60 deg, -3 % grade", -60.0, -0.03, (-40.0, 25.0, -3.0)),
    ("turned 135 deg, 8 % grade, survey coordinates", 135.0, 0.08, (500000.0, 4000000.0, 300.0)),
]


MODES = ("given", "given_origin_1cm_along", "estimated", "direction_estimated")


def rotation(yaw_deg: float, grade: float) -> np.ndarray:
    """Axis x turned yaw_deg about z after pitching it up by atan(grade); y stays horizontal."""
    p, y = np.arctan(grade), np.radians(yaw_deg)
    rz = np.array([[np.cos(y), -np.sin(y), 0.0], [np.sin(y), np.cos(y), 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[np.cos(p), 0.0, -np.sin(p)], [0.0, 1.0, 0.0], [np.sin(p), 0.0, np.cos(p)]])
    return rz @ ry


def surface_in_local_frame(xyz: np.ndarray, cfg):
    cloud = shotcrete.Cloud(xyz)
    frame = LocalFrame.of(cloud, cfg)
    local, local_cfg = frame.to_local(cloud, cfg)
    return _core.build_surface(local, local_cfg), frame


def volume_m3(td_m: np.ndarray, grid) -> float:
    """Required volume of cells with TD td_m (the ring between design line and wall), computed here
    independently of the core's missing_volume_m3."""
    t = td_m[np.isfinite(td_m) & (td_m > 0)]
    r = grid.profile.radius_m
    return float(np.sum(grid.dtheta_rad * grid.cell_size_m * (r * t + 0.5 * t * t)))


def case(bay_xyz: np.ndarray, cfg, ref, rot: np.ndarray, offset: np.ndarray, mode: str) -> dict:
    ref_volume = _core.missing_volume_m3(ref.grid)
    c = cfg.copy()
    c.profile.axis_origin_m = offset + (0.01 * rot[:, 0] if mode == "given_origin_1cm_along" else 0.0)
    c.profile.axis_direction = rot[:, 0]
    c.robot.base_position_m = rot @ np.asarray(cfg.robot.base_position_m) + offset  # the arm moves with the bay
    c.profile.estimate_axis = mode in ("estimated", "direction_estimated")
    c.profile.estimate_axis_origin = mode == "estimated"
    t0 = time.perf_counter()
    s, frame = surface_in_local_frame(bay_xyz @ rot.T + offset, c)
    seconds = time.perf_counter() - t0
    known = _core.TunnelAxis.from_direction(offset - frame.origin_m, rot[:, 0])
    td = np.asarray(_core.point_td(s.cloud, s.axis, s.profile))
    td_known = np.asarray(_core.point_td(s.cloud, known, s.profile))
    volume = _core.missing_volume_m3(s.grid)
    # The bay's own cells (untransformed grid), each cell's TD re-measured at its moved mean point
    # from this job's axis: the axis's effect on the required volume without the grid's end columns.
    valid = np.asarray(ref.grid.valid).ravel()  # (n_theta, n_d) -> cell index
    cells = np.asarray(ref.grid.mean_xyz)[valid] @ rot.T + offset - frame.origin_m
    td_cells = np.full(len(valid), np.nan)
    td_cells[valid] = np.asarray(_core.point_td(shotcrete.Cloud(cells), s.axis, s.profile))
    bay_volume = volume_m3(td_cells, ref.grid)
    assert abs(volume_m3(np.asarray(ref.grid.td_m).ravel(), ref.grid) / ref_volume - 1.0) < 1e-9  # same formula as the core
    try:
        plan = _core.plan_bay(s, c)
    except ValueError as e:  # recorded, not hidden (seen on 0f7458f: "dwell time 1337 must be finite")
        plan = None
        plan_error = str(e)
    residual = np.asarray(plan.td_after_m)[np.asarray(s.grid.valid).ravel()] if plan else np.array([np.nan])
    out = {
        "axis": mode,
        "volume_on_bay_cells_m3": round(bay_volume, 4),
        "volume_on_bay_cells_error_pct": round(100.0 * (bay_volume / ref_volume - 1.0), 3),
        "grid_volume_m3": round(volume, 4),
        "grid_volume_error_pct": round(100.0 * (volume / ref_volume - 1.0), 3),
        "mean_td_mm": round(1000.0 * float(td.mean()), 2),
        "mean_td_error_mm": round(1000.0 * float((td - td_known).mean()), 2),
        "worst_td_error_mm": round(1000.0 * float(np.abs(td - td_known).max()), 2),
        "direction_error_deg": round(float(np.degrees(np.arccos(min(1.0, abs(s.axis.ex @ rot[:, 0]))))), 4),
        "surface_s": round(seconds, 2),
        "planned_residual_rms_mm": round(1000.0 * float(np.sqrt(np.mean(residual ** 2))), 2),
        "planned_residual_min_max_mm": [round(1000.0 * float(residual.min()), 1), round(1000.0 * float(residual.max()), 1)],
    }
    if plan is None:
        out["plan_error"] = plan_error
    if s.axis_fit is not None:
        out.update(fit_rms_mm=round(1000.0 * s.axis_fit.rms_m, 1), fit_arc_deg=round(np.degrees(s.axis_fit.arc_rad), 1),
                   fit_points=s.axis_fit.points, fit_inlier_share=round(s.axis_fit.inlier_share, 4))
    return out


SCENE_PLACEMENTS = [("as generated", 0.0, 0.0, (0.0, 0.0, 0.0)), ("turned 30 deg, 5 % grade", 30.0, 0.05, (3.0, -2.0, 1.0))]


def scene_config(cfg):
    c = cfg.copy()
    c.synth.context_enabled = True
    c.synth.context_duct_diameter_m = 1.2
    c.synth.context_duct_gap_m = 0.3
    c.synth.context_rig_length_m = 4.0
    return c


def scene_cases(cfg, seed: int) -> list[dict]:
    sc = scene_config(cfg)
    sc.synth.seed = seed
    gen = _core.make_synthetic_bay(sc.synth)
    alone = _core.build_surface(gen.sample(cfg.grid.cell_size_m), cfg)
    alone_volume = _core.missing_volume_m3(alone.grid)
    scene_xyz = np.asarray(gen.sample_scan(cfg.grid.cell_size_m).xyz, dtype=np.float64)
    rows = []
    for name, yaw, grade, offset in SCENE_PLACEMENTS:
        rot, off = rotation(yaw, grade), np.asarray(offset, dtype=np.float64)
        for mode in ("given", "estimated"):
            c = cfg.copy()
            c.profile.axis_origin_m = off
            c.profile.axis_direction = rot[:, 0]
            c.profile.estimate_axis = mode == "estimated"
            t0 = time.perf_counter()
            try:
                s, frame = surface_in_local_frame(scene_xyz @ rot.T + off, c)
            except ValueError as e:  # the former fit refused the scene: recorded, not hidden
                rows.append({"seed": seed, "placement": name, "axis": mode, "refused": str(e)})
                print(json.dumps(rows[-1]), flush=True)
                continue
            seconds = time.perf_counter() - t0
            known = _core.TunnelAxis.from_direction(off - frame.origin_m, rot[:, 0])
            valid = np.asarray(s.grid.valid).ravel()
            td_cells = np.asarray(s.grid.td_m).ravel()[valid]
            pts = np.asarray(s.grid.mean_xyz)[valid]
            td_known = np.linalg.norm((pts - known.origin_m) - np.outer((pts - known.origin_m) @ known.ex, known.ex),
                                      axis=1) - s.profile.radius_m  # independent of the core's point_td
            err = td_cells - td_known
            volume = _core.missing_volume_m3(s.grid)
            row = {"seed": seed, "placement": name, "axis": mode, "scene_points": len(scene_xyz),
                   "bay_alone_volume_m3": round(alone_volume, 4), "bay_alone_cells": alone.grid.valid_count(),
                   "cells": s.grid.valid_count(), "bay_m": [round(s.bay.range.start_m, 3), round(s.bay.range.end_m, 3)],
                   "volume_m3": round(volume, 4), "volume_error_pct": round(100.0 * (volume / alone_volume - 1.0), 3),
                   "mean_td_error_mm": round(1000.0 * float(err.mean()), 2),
                   "worst_td_error_mm": round(1000.0 * float(np.abs(err).max()), 2),
                   "direction_error_deg": round(float(np.degrees(np.arccos(min(1.0, abs(s.axis.ex @ rot[:, 0]))))), 4),
                   "surface_s": round(seconds, 2)}
            if s.axis_fit is not None:
                row.update(fit_rms_mm=round(1000.0 * s.axis_fit.rms_m, 1), fit_arc_deg=round(np.degrees(s.axis_fit.arc_rad), 1),
                           fit_points=s.axis_fit.points, fit_inlier_share=round(s.axis_fit.inlier_share, 4))
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    parser.add_argument("--scenes-only", action="store_true", help="only the whole-scene cases")
    args = parser.parse_args()
    cfg = shotcrete.load_config()
    rows, scenes = [], []
    for seed in args.seeds:
        scenes += scene_cases(cfg, seed)
    for seed in ([] if args.scenes_only else args.seeds):
        cfg.synth.seed = seed
        bay = shotcrete.synthetic_cloud(cfg)
        ref = _core.build_surface(bay, cfg)
        ref_volume = _core.missing_volume_m3(ref.grid)
        ref_residual = np.asarray(_core.plan_bay(ref, cfg).td_after_m)[np.asarray(ref.grid.valid).ravel()]
        ref_rms_mm = round(1000.0 * float(np.sqrt(np.mean(ref_residual ** 2))), 2)
        xyz = np.asarray(bay.xyz, dtype=np.float64)
        for name, yaw, grade, offset in PLACEMENTS:
            rot = rotation(yaw, grade)
            for mode in MODES:
                row = {"seed": seed, "placement": name, "reference_volume_m3": round(ref_volume, 4),
                       "reference_residual_rms_mm": ref_rms_mm,
                       **case(xyz, cfg, ref, rot, np.asarray(offset, dtype=np.float64), mode)}
                rows.append(row)
                print(json.dumps(row), flush=True)
    summary = {}
    for mode in ("given", "estimated"):
        sel = [r for r in scenes if r["axis"] == mode]
        ok = [r for r in sel if "refused" not in r]
        summary["scene_" + mode] = {
            "refused": len(sel) - len(ok),
            "worst_mean_td_error_mm": max((abs(r["mean_td_error_mm"]) for r in ok), default=None),
            "worst_cell_td_error_mm": max((r["worst_td_error_mm"] for r in ok), default=None),
            "worst_direction_error_deg": max((r["direction_error_deg"] for r in ok), default=None),
            "worst_volume_error_pct": max((abs(r["volume_error_pct"]) for r in ok), default=None),
            "meets_target": bool(ok) and len(ok) == len(sel) and all(abs(r["volume_error_pct"]) <= 1.0 for r in ok),
        }
    for mode in ([] if args.scenes_only else MODES):
        sel = [r for r in rows if r["axis"] == mode]
        summary[mode] = {
            "worst_volume_on_bay_cells_error_pct": max(abs(r["volume_on_bay_cells_error_pct"]) for r in sel),
            "worst_grid_volume_error_pct": max(abs(r["grid_volume_error_pct"]) for r in sel),
            "worst_mean_td_error_mm": max(abs(r["mean_td_error_mm"]) for r in sel),
            "worst_point_td_error_mm": max(r["worst_td_error_mm"] for r in sel),
            "worst_direction_error_deg": max(r["direction_error_deg"] for r in sel),
            "worst_residual_rms_change_mm": max((abs(r["planned_residual_rms_mm"] - r["reference_residual_rms_mm"])
                                                 for r in sel if "plan_error" not in r), default=None),
            "plan_errors": sum("plan_error" in r for r in sel),
            "meets_target": all(abs(r["volume_on_bay_cells_error_pct"]) <= 1.0 for r in sel),
        }
    result = {
        "benchmark": "axis: required volume and TD of transformed synthetic bays, axis given vs estimated",
        "bay": "default synth (half cylinder, R 5.6 m, 1.2 m, 30 pits, 5 mm noise)",
        "target": "required volume within 1 % of the untransformed bay (on the bay's cells)",
        "modes": {"given": "the known axis", "given_origin_1cm_along": "the known axis, origin 1 cm along it "
                  "(control: the grid's end columns alone change grid_volume by a few per cent)",
                  "estimated": "profile.estimate_axis", "direction_estimated":
                  "profile.estimate_axis with estimate_axis_origin false (the surveyed origin kept)"},
        "scene": "the same bay in the generator's whole scene: lined previous bay 2 m, invert 1.5 m under the springlines, "
                 "face, duct 1.2 m diameter 0.3 m under the crown, rig carrier 4 m; target: required volume within 1 % "
                 "of the bay alone's (known axis)",
        "summary": summary,
        "scene_cases": scenes,
        "cases": rows,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / ("axis_scenes.json" if args.scenes_only else "axis.json")).write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
