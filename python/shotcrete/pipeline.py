"""The end-to-end job behind ``shotcrete demo`` and ``shotcrete plan``:
scan -> surface -> graded/optimal plan with simulated deposition -> report, figures, files."""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

import numpy as np

from . import _core, plots, report
from .io import write_cloud

Progress = Callable[[str, float], None]


def levels_dict(levels) -> dict[int, int]:
    return {int(k): int(v) for k, v in dict(levels).items()}


def residual_stats_mm(td_m: np.ndarray, valid: np.ndarray) -> dict:
    r = np.asarray(td_m)[np.asarray(valid)] * 1000.0
    return {"mean": float(r.mean()), "min": float(r.min()), "max": float(r.max()),
            "rms": float(np.sqrt(np.mean(r ** 2))), "abs_max": float(np.abs(r).max())}


def plan_to_dict(plan, surface) -> dict:
    """The plan as plain data: rounds -> regions (in spraying order) -> passes (waypoints in m, speeds in m/s)."""
    rounds = []
    for i, rnd in enumerate(plan.rounds):
        regions = []
        for reg in rnd.regions:
            regions.append({
                "cells": len(reg.region.cells),
                "target_thickness_m": round(reg.target_thickness_m, 5),
                "spacing_m": round(reg.spacing_m, 4),
                "reversed": bool(reg.reversed),
                "note": reg.note,
                "passes": [{
                    "line": p.line,
                    "speed_mps": round(p.speed_mps, 5),
                    "length_m": round(p.length_m, 4),
                    "duration_s": round(p.duration_s(), 3),
                    "speed_profile_mps": np.round(p.speed_profile_mps, 5).tolist(),
                    "positions_m": np.round(p.positions_m, 4).tolist(),
                    "axes": np.round(p.axes, 5).tolist(),
                } for p in reg.passes],
            })
        rounds.append({"round": i + 1, "kind": rnd.kind, "level": rnd.level, "order": list(rnd.order),
                       "order_method": rnd.order_method, "link_length_m": rnd.link_length_m,
                       "spray_time_s": rnd.spray_time_s, "regions": regions})
    return {"frame": "tunnel (x along the axis, y across, z up), metres", "rounds": rounds,
            "stop_reason": plan.stop_reason}


def ik_report(arm_plan, robot, check_every: int = 10) -> dict:
    """The IK figures for report.json from a planned and timed bay (``_core.plan_for_arm``). An
    unreachable waypoint is reported (by region and waypoint, as the core names it), not dropped:
    the trajectory is then None and ``ik["error"]`` says why."""
    plan, traj = arm_plan.plan, arm_plan.trajectory
    regions = [list(reg.passes) for rnd in plan.rounds for reg in rnd.regions]
    ik = {"poses": int(sum(len(p.waypoints) for reg in regions for p in reg)), "regions": len(regions),
          "replans": int(arm_plan.replans), "learned_speed_bounds": len(arm_plan.learned.speed_mps)}
    if not regions:
        return {**ik, "solved": True}
    if traj is None:
        return {**ik, "solved": False, "error": arm_plan.timing_error}
    # Independent check of the tracking: FK of the joint samples against the nozzle poses.
    q, pos, axes = traj.q, traj.positions, traj.axes
    worst_m = worst_rad = 0.0
    for i in range(0, len(traj), max(1, check_every)):
        T = robot.fk(q[i])
        worst_m = max(worst_m, float(np.linalg.norm(T[:3, 3] - pos[i])))
        worst_rad = max(worst_rad, float(np.arccos(np.clip(T[:3, 2] @ axes[i], -1.0, 1.0))))
    return {**ik, "solved": True, "samples_checked": len(range(0, len(traj), max(1, check_every))),
            "worst_position_error_m": worst_m, "worst_angle_error_rad": worst_rad,
            "untracked_regions": int(traj.untracked_regions)}


def swarm_report(arm_plan) -> dict:
    """The timing swarm's figures (timing.tune_with_pso) of a ``_core.plan_for_arm`` result."""
    tun, traj = arm_plan.tuning, arm_plan.trajectory
    return {"used": bool(arm_plan.tuned_timing_used), "error": arm_plan.tuning_error or None,
            "config_timing_duration_s": arm_plan.config_duration_s,
            "duration_s": traj.duration_s if traj is not None else None,
            "regions_tuned": int(sum(tun.feasible)) if tun else 0, "regions": len(tun.feasible) if tun else 0,
            "evaluations": int(sum(p.evaluations for p in tun.pso)) if tun else 0,
            "params": [p.to_dict() for p in tun.params] if tun else []}


def _pass_tracks(plan_round, surface):
    """Per pass: (d, s) of the wall point it aims at, and its speed, for the map figures."""
    axis, radius = surface.axis, surface.profile.radius_m
    tracks = []
    for reg in plan_round.regions:
        for p in reg.passes:
            pos, ax = p.positions_m, p.axes
            target = pos + ax  # the wall is about one standoff along the spray axis
            cyl = np.array([axis.to_cylindrical(q) for q in target[:: max(1, len(target) // 40)]])
            tracks.append((cyl[:, 2], cyl[:, 1] * radius, p.speed_mps))
    return tracks


def run_job(cloud: _core.Cloud, config: _core.Config, out: Path, progress: Progress | None = None,
            inputs: list[Path] = ()) -> dict:
    """Run the whole chain on ``cloud`` and write report.json, report.html, plan.json, figures and
    the sprayed cloud to ``out``. Returns the report as a dict."""
    progress = progress or (lambda stage, fraction: None)
    out = report.prepare_out_dir(Path(out), list(inputs))
    t0 = time.perf_counter()
    progress("surface", 0.0)
    surface = _core.build_surface(cloud, config)
    timings = {f"surface_{k}": float(v) for k, v in surface.timings_s.items()}
    progress("surface", 1.0)

    grid = surface.grid
    valid = np.asarray(grid.valid).reshape(-1)
    td_before = np.asarray(grid.td_m).reshape(-1)
    result: dict = {
        "mode": config.planner.mode,
        "cells": int(grid.valid_count()),
        "grid_shape": [int(grid.n_theta), int(grid.n_d)],
        "points_in": int(len(cloud)),
        "points_used": int(len(surface.cloud)),
        "design_radius_m": float(surface.profile.radius_m),
        "axis_fit_rms_m": float(surface.axis_fit_rms_m),
        "levels_before": levels_dict(_core.level_counts(surface.levels)),
        "td_before_mm": residual_stats_mm(td_before, valid),
    }

    # Planned for the arm: every pass within the speeds its joints can follow, then timed; where
    # the timed passes still break a joint limit the bay is planned again at lower speeds there.
    from .cli_robot import load_robot

    robot = load_robot(config)
    t_plan = time.perf_counter()
    arm_plan = _core.plan_for_arm(surface, config, robot, progress)
    plan, trajectory = arm_plan.plan, arm_plan.trajectory
    timings["plan_simulate_and_time"] = time.perf_counter() - t_plan
    for k, v in plan.timings_s.items():
        timings[f"planner_{k}"] = float(v)
    after = np.asarray(plan.td_after_m)
    levels_after = [_core.level_of_td_mm(x * 1000.0) if ok else _core.NO_DATA_LEVEL
                    for x, ok in zip(after, valid)]
    passes = sum(len(reg.passes) for rnd in plan.rounds for reg in rnd.regions)
    result.update({
        "levels_after": levels_dict(_core.level_counts(levels_after)),
        "residual_mm": residual_stats_mm(after, valid),
        "rounds": len(plan.rounds),
        "regions": sum(len(rnd.regions) for rnd in plan.rounds),
        "passes": passes,
        "stop_reason": plan.stop_reason,
        "warnings": list(plan.warnings),
        "unreachable_cells": len(plan.unreachable_cells),
        "spray_time_s": plan.spray_time_s,
        "required_volume_m3": plan.required_volume_m3,
        "deposition_rate_m3ph": plan.deposition_rate_m3ps * 3600.0,
        "physical_limit_s": plan.physical_limit_s,
        "spray_time_ratio": plan.spray_time_s / plan.physical_limit_s if plan.physical_limit_s > 0 else None,
        "sprayed_volume_m3": plan.spray_time_s * plan.deposition_rate_m3ps,
        "link_length_m": sum(rnd.link_length_m for rnd in plan.rounds),
        "speed_capped": int(plan.speed_capped),
        "rounds_detail": [{"round": i + 1, "kind": r.kind, "level": r.level, "regions": len(r.regions),
                           "passes": sum(len(g.passes) for g in r.regions), "spray_time_s": r.spray_time_s,
                           "order_method": r.order_method, "link_length_m": r.link_length_m,
                           "levels_before": levels_dict(r.levels_before), "levels_after": levels_dict(r.levels_after)}
                          for i, r in enumerate(plan.rounds)],
    })
    result["ik"] = ik_report(arm_plan, robot)
    if trajectory is not None:
        result["total_time_s"] = trajectory.duration_s
        result["trajectory"] = {
            "duration_s": trajectory.duration_s, "spray_time_s": trajectory.spray_time_s,
            "transit_time_s": trajectory.transit_time_s, "samples": len(trajectory),
            "rate_hz": config.timing.trajectory_rate_hz,
            "max_velocity_ratio": trajectory.max_velocity_ratio,
            "max_acceleration_ratio": trajectory.max_acceleration_ratio,
            "max_position_violation_rad": trajectory.max_position_violation_rad,
            "max_position_violation_m": trajectory.max_position_violation_m,
            "config_timing_duration_s": arm_plan.config_duration_s,
        }
        if arm_plan.tuning is not None or arm_plan.tuning_error:
            result["trajectory"]["swarm"] = swarm_report(arm_plan)
    else:
        result["total_time_s"] = None

    progress("report", 0.0)
    t_report = time.perf_counter()
    figs_dir = out / "figures"
    vmax = max(50.0, float(np.nanmax(np.abs(td_before[valid]))) * 1000.0)
    figures = [
        ("TD before spraying", plots.td_map(grid, figs_dir / "td_before.png", "TD before spraying", vmax)),
        ("Levels before spraying", plots.level_map(grid, surface.levels, figs_dir / "levels_before.png",
                                                   "Levels before spraying")),
    ]
    counts, labels = [result["levels_before"]], ["before"]
    for i, rnd in enumerate(plan.rounds):
        tracks = _pass_tracks(rnd, surface)
        figures.append((f"Round {i + 1} ({rnd.kind}, level {rnd.level}): passes over the TD map before it",
                        plots.passes_map(grid, (td_before if i == 0 else np.asarray(plan.rounds[i - 1].td_after_m)),
                                         tracks, figs_dir / f"round{i + 1}_passes.png",
                                         f"Round {i + 1}: {len(tracks)} passes", vmax)))
        figures.append((f"TD after round {i + 1}",
                        plots.td_map_flat(grid, np.asarray(rnd.td_after_m), figs_dir / f"round{i + 1}_td_after.png",
                                          f"TD after round {i + 1}", vmax)))
        lv = [_core.level_of_td_mm(x * 1000.0) if ok else _core.NO_DATA_LEVEL
              for x, ok in zip(np.asarray(rnd.td_after_m), valid)]
        figures.append((f"Levels after round {i + 1}",
                        plots.level_map(grid, lv, figs_dir / f"round{i + 1}_levels.png", f"Levels after round {i + 1}")))
        counts.append(levels_dict(rnd.levels_after))
        labels.append(f"after round {i + 1}")
    figures.append(("Cells per level, per round", plots.level_counts_chart(counts, labels, figs_dir / "level_counts.png")))
    if plan.rounds:
        figures.append(("Nozzle speed per pass", plots.speeds_chart(plan, figs_dir / "speeds.png")))
    figures.append(("Residual after spraying (TD, mm)",
                    plots.td_map_flat(grid, after, figs_dir / "td_after.png", "Residual TD after spraying", 50.0)))

    (out / "plan.json").write_text(json.dumps(plan_to_dict(plan, surface)) + "\n")
    if trajectory is not None:
        np.savez_compressed(out / "trajectory.npz", t_s=trajectory.t_s, q=trajectory.q, qd=trajectory.qd,
                            qdd=trajectory.qdd, nozzle_position_m=trajectory.positions, nozzle_axis=trajectory.axes,
                            spraying=trajectory.spraying, pass_index=trajectory.pass_index,
                            region_index=trajectory.region_index)
    write_cloud(out / "surface.ply", surface.cloud, _core.point_td(surface.cloud, surface.axis, surface.profile))
    write_cloud(out / "sprayed.ply", plan.sprayed_cloud,
                _core.point_td(plan.sprayed_cloud, surface.axis, surface.profile))
    timings["report"] = time.perf_counter() - t_report
    timings["total"] = time.perf_counter() - t0
    result["timings_s"] = timings
    result["files"] = {"plan": "plan.json", "surface_cloud": "surface.ply", "sprayed_cloud": "sprayed.ply"}
    if trajectory is not None:
        result["files"]["trajectory"] = "trajectory.npz"  # t_s, q, qd, qdd (joint order of the URDF), nozzle
    report.write_json(out / "report.json", result)
    report.write_html(out, result, [(cap, str(p.relative_to(out))) for cap, p in figures])
    progress("report", 1.0)
    return result
