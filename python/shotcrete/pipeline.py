"""The end-to-end job behind ``shotcrete demo`` and ``shotcrete plan``, in named steps:
scan -> surface -> plan for the arm -> summary (the core's JobSummary) -> figures -> files
(report.json, report.html, plan.json, trajectory.npz, clouds)."""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

import numpy as np

from . import _core, plots, report
from .io import write_cloud
from .outdir import job_output
from .planning import plan_surface
from .robot import load_robot
from .survey import LocalFrame

Progress = Callable[[str, float], None]


def _no_progress(stage: str, fraction: float) -> None:
    pass


def run_job(cloud: _core.Cloud | Callable[[], _core.Cloud], config: _core.Config, out: Path,
            progress: Progress | None = None, inputs: dict[str, Path] | None = None) -> dict:
    """Run the whole chain on ``cloud`` (or the cloud a loader returns, called once ``out`` is
    locked, so a second job on ``out`` fails before reading anything) and write report.json, report.html, plan.json, figures and
    the sprayed cloud to ``out`` (locked, written beside it and moved into place when complete:
    ``outdir.job_output``). ``inputs``: the files the job read by role ("cloud", "config"), hashed
    into report.json's ``provenance``. Returns the report as a dict: the core's job summary
    (``_core.summarise_job``) plus ``timings_s``, ``files`` and ``provenance``."""
    progress = progress or _no_progress
    inputs = {k: Path(v) for k, v in (inputs or {}).items() if v is not None}
    with job_output(Path(out), inputs.values()) as tmp:
        t0 = time.perf_counter()
        cloud = cloud() if callable(cloud) else cloud
        given_cloud, given_config = cloud, config  # provenance: what the user gave
        frame = LocalFrame.of(cloud, config)  # survey coordinates: run in a local frame, write back
        cloud, config = frame.to_local(cloud, config)
        surface, timings = surface_step(cloud, config, progress)
        robot = load_robot(config)
        arm_plan = plan_step(surface, config, robot, progress, timings)
        summary = _core.summarise_job(surface, arm_plan, robot, config, points_in=len(cloud))
        result = summary.to_dict()
        result["local_origin_m"] = frame.origin_m.tolist()  # outputs are in the input's frame
        result["axis"]["origin_m"] = (np.asarray(result["axis"]["origin_m"]) + frame.origin_m).tolist()

        progress("report", 0.0)
        t_report = time.perf_counter()
        figures = figures_step(tmp / "figures", surface, arm_plan.plan, summary, arm_plan.executed)
        files = files_step(tmp, surface, arm_plan, frame, robot)
        timings["report"] = time.perf_counter() - t_report
        timings["total"] = time.perf_counter() - t0
        result["timings_s"] = timings
        result["files"] = files
        result["provenance"] = report.provenance(given_config, given_cloud, inputs)
        report.write_json(tmp / "report.json", result)
        report.write_html(tmp, result, [(cap, str(p.relative_to(tmp))) for cap, p in figures])
    progress("report", 1.0)
    return result


def surface_step(cloud, config, progress: Progress):
    """The surface of the scan, and the timings dict the job fills (surface_<stage> [s])."""
    progress("surface", 0.0)
    surface = _core.build_surface(cloud, config)
    progress("surface", 1.0)
    return surface, {f"surface_{k}": float(v) for k, v in surface.timings_s.items()}


def plan_step(surface, config, robot, progress: Progress, timings: dict):
    """The bay planned, simulated and timed for the arm (``planning.plan_surface``): every pass
    within the speeds its joints can follow; where the timed passes still break a joint limit the
    bay is planned again at lower speeds there. Adds the planner's timings to ``timings``."""
    t_plan = time.perf_counter()
    arm_plan = plan_surface(surface, config, progress, robot=robot)
    timings["plan_simulate_and_time"] = time.perf_counter() - t_plan
    for k, v in arm_plan.plan.timings_s.items():
        timings[f"planner_{k}"] = float(v)
    return arm_plan


def figures_step(figs_dir: Path, surface, plan, summary, executed=None) -> list[tuple[str, Path]]:
    """The report's figures as (caption, file): TD and levels before, each round's passes, TD and
    levels after it (the planner's estimate), cells per level per round, speeds, the residual (of
    the executed deposit when there is one: ``executed``, an ExecutedDeposit) and the planner's."""
    figs_dir.mkdir(parents=True, exist_ok=True)
    grid = surface.grid
    valid = np.asarray(grid.valid).reshape(-1)
    td_before = np.asarray(grid.td_m).reshape(-1)
    vmax = max(50.0, float(np.nanmax(np.abs(td_before[valid]))) * 1000.0)
    figures = [
        ("TD before spraying", plots.td_map(grid, figs_dir / "td_before.png", "TD before spraying", vmax)),
        ("Levels before spraying", plots.level_map(grid, surface.levels, figs_dir / "levels_before.png",
                                                   "Levels before spraying")),
    ]
    counts, labels = [dict(summary.levels_before)], ["before"]
    for i, rnd in enumerate(plan.rounds):
        n = i + 1
        tracks = _pass_tracks(rnd, surface)
        td_round_before = td_before if i == 0 else np.asarray(plan.rounds[i - 1].td_after_m)
        figures.append((f"Round {n} ({rnd.kind}, level {rnd.level}): passes over the TD map before it",
                        plots.passes_map(grid, td_round_before, tracks, figs_dir / f"round{n}_passes.png",
                                         f"Round {n}: {len(tracks)} passes", vmax)))
        td_after = np.asarray(rnd.td_after_m)
        figures.append((f"TD after round {n}", plots.td_map_flat(grid, td_after, figs_dir / f"round{n}_td_after.png",
                                                                 f"TD after round {n}", vmax)))
        lv = [_core.level_of_td_mm(x * 1000.0) if ok else _core.NO_DATA_LEVEL for x, ok in zip(td_after, valid)]
        figures.append((f"Levels after round {n}",
                        plots.level_map(grid, lv, figs_dir / f"round{n}_levels.png", f"Levels after round {n}")))
        counts.append(dict(rnd.levels_after))
        labels.append(f"after round {n}")
    figures.append(("Cells per level, per round", plots.level_counts_chart(counts, labels, figs_dir / "level_counts.png")))
    if plan.rounds:
        figures.append(("Nozzle speed per pass", plots.speeds_chart(plan, figs_dir / "speeds.png")))
    if executed is not None:
        figures.append(("Residual after spraying, executed along the trajectory with the pump's flow (TD, mm)",
                        plots.td_map_flat(grid, np.asarray(executed.td_after_m), figs_dir / "td_after.png",
                                          "Residual TD after spraying (executed)", 50.0)))
        figures.append(("Residual the planner estimated (TD, mm)",
                        plots.td_map_flat(grid, np.asarray(plan.td_after_m), figs_dir / "td_after_planned.png",
                                          "Residual TD after spraying (planned)", 50.0)))
    else:
        figures.append(("Residual after spraying, the planner's estimate: no trajectory (TD, mm)",
                        plots.td_map_flat(grid, np.asarray(plan.td_after_m), figs_dir / "td_after.png",
                                          "Residual TD after spraying (planned)", 50.0)))
    return figures


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


def files_step(out: Path, surface, arm_plan, frame: LocalFrame | None = None, robot=None) -> dict:
    """plan.json, trajectory.npz (when timed), surface.ply and sprayed.ply (the executed deposit's
    wall when timed), every coordinate in the input's frame (``frame``'s origin added back);
    returns report.json's ``files`` entry."""
    plan, trajectory = arm_plan.plan, arm_plan.trajectory
    frame = frame or LocalFrame(np.zeros(3))
    (out / "plan.json").write_text(json.dumps(plan_to_dict(plan, frame.origin_m)) + "\n")
    files = {"plan": "plan.json", "surface_cloud": "surface.ply", "sprayed_cloud": "sprayed.ply"}
    if trajectory is not None:
        np.savez_compressed(out / "trajectory.npz", t_s=trajectory.t_s, q=trajectory.q, qd=trajectory.qd,
                            qdd=trajectory.qdd, nozzle_position_m=frame.points_to_input(trajectory.positions),
                            nozzle_axis=trajectory.axes, base_position_m=_base_position(robot, frame),
                            spraying=trajectory.spraying, pass_index=trajectory.pass_index,
                            region_index=trajectory.region_index)
        files["trajectory"] = "trajectory.npz"  # t_s, q, qd, qdd (joint order of the URDF), nozzle
    write_cloud(out / "surface.ply", frame.cloud_to_input(surface.cloud),
                _core.point_td(surface.cloud, surface.axis, surface.profile))
    # The wall as the trajectory sprays it; the planner's estimate without a trajectory.
    sprayed = arm_plan.executed.sprayed_cloud if arm_plan.executed is not None else plan.sprayed_cloud
    write_cloud(out / "sprayed.ply", frame.cloud_to_input(sprayed), _core.point_td(sprayed, surface.axis, surface.profile))
    return files


def _base_position(robot, frame: LocalFrame) -> np.ndarray:
    """The robot's base_link position in the input's frame (NaN when no robot was given)."""
    if robot is None:
        return np.full(3, np.nan)
    return frame.points_to_input(np.asarray(robot.base_pose)[:3, 3])


def plan_to_dict(plan, origin_m=(0.0, 0.0, 0.0)) -> dict:
    """The plan as plain data: rounds -> regions (in spraying order) -> passes (waypoints in m, speeds
    in m/s); waypoints in the input's frame (``origin_m``, the local frame's origin, added)."""
    origin_m = np.asarray(origin_m, dtype=np.float64)
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
                    "positions_m": np.round(np.asarray(p.positions_m) + origin_m, 4).tolist(),
                    "axes": np.round(p.axes, 5).tolist(),
                } for p in reg.passes],
            })
        rounds.append({"round": i + 1, "kind": rnd.kind, "level": rnd.level, "order": list(rnd.order),
                       "order_method": rnd.order_method, "link_length_m": rnd.link_length_m,
                       "spray_time_s": rnd.spray_time_s, "regions": regions})
    return {"frame": "the input cloud's frame, metres", "local_origin_m": origin_m.tolist(), "rounds": rounds,
            "stop_reason": plan.stop_reason}
