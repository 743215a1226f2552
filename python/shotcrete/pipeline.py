"""The end-to-end job behind ``shotcrete demo`` and ``shotcrete plan``, in named steps:
scan -> surface -> plan for the arm -> summary (the core's JobSummary) -> figures -> files
(report.json, report.html, plan.json, trajectory.npz, cells.csv, clouds)."""
from __future__ import annotations

import json
import time
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable

import numpy as np

from . import _core, plots, report, view3d
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
    locked, so a second job on ``out`` fails before reading anything) and write report.json,
    report.html (with plotly.min.js and figures/ beside it), plan.json, cells.csv and the clouds to
    ``out`` (locked, written beside it and moved into place when complete: ``outdir.job_output``).
    ``inputs``: the files the job read by role ("cloud", "config"), hashed into report.json's
    ``provenance``. Returns the report as a dict: the core's job summary
    (``_core.summarise_job``) plus ``timings_s``, ``files`` and ``provenance``."""
    progress = progress or _no_progress
    inputs = {k: Path(v) for k, v in (inputs or {}).items() if v is not None}
    with job_output(Path(out), inputs.values()) as tmp:
        t0 = time.perf_counter()
        cloud = cloud() if callable(cloud) else cloud
        given_cloud, given_config = cloud, config  # provenance: what the user gave
        # profile.alignment_path: the axis where the scan lies, in the input's frame (double precision).
        on_alignment = None
        if config.profile.alignment_path:  # (no copy of a large cloud in metres otherwise)
            config, on_alignment = _core.with_alignment_axis(config, np.asarray(cloud.xyz) * config.io.unit_scale)
        frame = LocalFrame.of(cloud, config)  # survey coordinates: run in a local frame, write back
        cloud, config = frame.to_local(cloud, config)
        surface, timings = surface_step(cloud, config, progress)
        robot = load_robot(config)
        arm_plan = plan_step(surface, config, robot, progress, timings)
        robot = _core.placed_robot(robot, arm_plan.base_placement)  # where the job stood the arm (robot.place_base)
        summary = _core.summarise_job(surface, arm_plan, robot, config, points_in=len(cloud))
        result = summary.to_dict()
        result["local_origin_m"] = frame.origin_m.tolist()  # outputs are in the input's frame
        result["axis"]["origin_m"] = (np.asarray(result["axis"]["origin_m"]) + frame.origin_m).tolist()
        if "base_placement" in result:
            for key in ("configured_m", "position_m"):
                result["base_placement"][key] = (np.asarray(result["base_placement"][key]) + frame.origin_m).tolist()
        if on_alignment is not None:
            result["alignment"] = alignment_entry(given_config.profile.alignment_path, on_alignment)
            if on_alignment.deviation_m > ALIGNMENT_WARN_M:
                result["warnings"].append(
                    f"the alignment curves {on_alignment.deviation_m * 1000:.0f} mm off the straight axis over the scan "
                    f"(chainage {on_alignment.start_m:.2f}..{on_alignment.end_m:.2f} m): TD is uncertain by up to that")
        for link in (result.get("clearance") or {}).get("links", []):
            link["closest_m"] = (link["closest_m"] + frame.origin_m).tolist()

        progress("report", 0.0)
        t_report = time.perf_counter()
        # The files (trajectory.npz's deflate, about 1 s on the default bay, frees the GIL) are
        # written on a second thread while the figures are drawn.
        with ThreadPoolExecutor(max_workers=1) as pool:
            files_written = pool.submit(files_step, tmp, surface, arm_plan, frame, robot)
            figures = figures_step(tmp / "figures", surface, arm_plan.plan, summary, arm_plan.executed)
            facts = page_step(tmp, surface, arm_plan, config, robot)
            files = files_written.result()
        timings["report"] = time.perf_counter() - t_report
        timings["total"] = time.perf_counter() - t0
        result["timings_s"] = timings
        result["files"] = files
        result["provenance"] = report.provenance(given_config, given_cloud, inputs)
        report.write_json(tmp / "report.json", result)
        report.write_html(tmp, result, [(g, cap, str(p.relative_to(tmp))) for g, cap, p in figures], facts)
    progress("report", 1.0)
    return result


ALIGNMENT_WARN_M = 0.01  # a straight axis further than this from the alignment over the scan is worth a warning


def alignment_entry(path: str, at) -> dict:
    """report.json ``alignment``: where on the alignment the job's axis lies and how straight it is there."""
    return {"path": path, "chainage_m": at.chainage_m, "start_m": at.start_m, "end_m": at.end_m,
            "deviation_m": at.deviation_m, "scan_offset_m": at.scan_offset_m}


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
    timings["base_placement"] = arm_plan.base_placement.seconds
    return arm_plan


def figures_step(figs_dir: Path, surface, plan, summary, executed=None) -> list[tuple[str, str, Path]]:
    """The report's figures as (group, caption, file), group "summary" | "before" | "round N" |
    "after": the thickness classes after spraying, TD and levels before, each round's passes, TD
    and levels after it (the planner's estimate), then the residual (of the executed deposit when
    there is one: ``executed``, an ExecutedDeposit) and the planner's, cells per level per round,
    speeds. Every TD map on one colour scale (plots.TD_BOUNDS_MM)."""
    figs_dir.mkdir(parents=True, exist_ok=True)
    grid = surface.grid
    valid = np.asarray(grid.valid).reshape(-1)
    td_before = np.asarray(grid.td_m).reshape(-1)

    def levels_of(td):
        return [_core.level_of_td_mm(x * 1000.0) if ok else _core.NO_DATA_LEVEL for x, ok in zip(td, valid)]

    td_final = np.asarray(executed.td_after_m if executed is not None else plan.td_after_m)
    which = "executed" if executed is not None else "planned"
    tol = report.LEVEL0_TOLERANCE_MM
    figures = [
        ("summary", f"Thickness classes after spraying ({which}): missing more than {tol:.0f} mm, within "
                    f"±{tol:.0f} mm, over-filled by more than {tol:.0f} mm",
         plots.class_map(grid, levels_of(td_final), figs_dir / "classes_after.png",
                         f"Thickness after spraying ({which})", tol)),
        ("before", "TD before spraying", plots.td_map(grid, figs_dir / "td_before.png", "TD before spraying")),
        ("before", "Levels before spraying", plots.level_map(grid, surface.levels, figs_dir / "levels_before.png",
                                                             "Levels before spraying")),
    ]
    counts, labels = [dict(summary.levels_before)], ["before"]
    for i, rnd in enumerate(plan.rounds):
        n = i + 1
        group = f"round {n} ({rnd.kind}, level {rnd.level})"
        tracks = _pass_tracks(rnd, surface)
        td_round_before = td_before if i == 0 else np.asarray(plan.rounds[i - 1].td_after_m)
        figures.append((group, f"Round {n} ({rnd.kind}, level {rnd.level}): passes over the TD map before it",
                        plots.passes_map(grid, td_round_before, tracks, figs_dir / f"round{n}_passes.png",
                                         f"Round {n}: {len(tracks)} passes")))
        td_after = np.asarray(rnd.td_after_m)
        figures.append((group, f"TD after round {n}", plots.td_map_flat(grid, td_after, figs_dir / f"round{n}_td_after.png",
                                                                        f"TD after round {n}")))
        figures.append((group, f"Levels after round {n}",
                        plots.level_map(grid, levels_of(td_after), figs_dir / f"round{n}_levels.png",
                                        f"Levels after round {n}")))
        counts.append(dict(rnd.levels_after))
        labels.append(f"after round {n}")
    if executed is not None:
        figures.append(("after", "Residual after spraying, executed along the trajectory with the pump's flow (TD, mm)",
                        plots.td_map_flat(grid, np.asarray(executed.td_after_m), figs_dir / "td_after.png",
                                          "Residual TD after spraying (executed)")))
        figures.append(("after", "Residual the planner estimated (TD, mm)",
                        plots.td_map_flat(grid, np.asarray(plan.td_after_m), figs_dir / "td_after_planned.png",
                                          "Residual TD after spraying (planned)")))
    else:
        figures.append(("after", "Residual after spraying, the planner's estimate: no trajectory (TD, mm)",
                        plots.td_map_flat(grid, np.asarray(plan.td_after_m), figs_dir / "td_after.png",
                                          "Residual TD after spraying (planned)")))
    figures.append(("after", "Cells per level, per round",
                    plots.level_counts_chart(counts, labels, figs_dir / "level_counts.png")))
    if plan.rounds:
        figures.append(("after", "Nozzle speed per pass", plots.speeds_chart(plan, figs_dir / "speeds.png")))
    return figures


def page_step(out: Path, surface, arm_plan, config, robot=None) -> report.PageFacts:
    """What report.html shows beside report.json: the summary's per-cell facts (report.page_facts)
    and the 3-D view (view3d, writes plotly.min.js into ``out``)."""
    executed = arm_plan.executed
    table = report.cell_table(surface, arm_plan.plan, executed)
    td_after = executed.td_after_m if executed is not None else arm_plan.plan.td_after_m
    base = np.asarray(robot.base_pose)[:3, 3] if robot is not None else None
    view = view3d.figure_html(out, surface, arm_plan.plan, td_after, arm_plan.trajectory, base,
                              "after spraying" if executed is not None else "after spraying (planned)")
    return report.page_facts(surface, table, config, view)


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


def _pump_arrays(executed, trajectory) -> dict:
    """The pump as it runs on the trajectory: flow (share of full flow, 0..1) at every sample and the
    switch instants (ramps centred on them); nothing without an executed deposit."""
    if executed is None:
        return {}
    flow = executed.flow
    return {"flow": np.array([flow.flow_at(t) for t in trajectory.t_s]),
            "flow_on_s": np.asarray(flow.on_s), "flow_off_s": np.asarray(flow.off_s)}


def files_step(out: Path, surface, arm_plan, frame: LocalFrame | None = None, robot=None) -> dict:
    """plan.json, trajectory.npz (when timed), cells.csv (report.write_cells_csv), surface.ply and
    sprayed.ply (the executed deposit's wall when timed), every coordinate in the input's frame (``frame``'s origin added back);
    returns report.json's ``files`` entry."""
    plan, trajectory = arm_plan.plan, arm_plan.trajectory
    frame = frame or LocalFrame(np.zeros(3))
    (out / "plan.json").write_text(json.dumps(plan_to_dict(plan, frame.origin_m)) + "\n")
    files = {"plan": "plan.json", "surface_cloud": "surface.ply", "sprayed_cloud": "sprayed.ply"}
    if trajectory is not None:
        _save_npz(out / "trajectory.npz", t_s=trajectory.t_s, q=trajectory.q, qd=trajectory.qd,
                  qdd=trajectory.qdd, nozzle_position_m=frame.points_to_input(trajectory.positions),
                  nozzle_axis=trajectory.axes, base_position_m=_base_position(robot, frame),
                  spraying=trajectory.spraying, pass_index=trajectory.pass_index,
                  region_index=trajectory.region_index, segment_kind=trajectory.kind,
                  **_pump_arrays(arm_plan.executed, trajectory))
        # t_s, q, qd, qdd (joint order of the URDF), nozzle, flow; segment_kind: 0 pass, 1 turn arc,
        # 2 lead, 3 link (turn runs, stops, creeps, spray-off gaps), 4 joint move (_core.SegmentKind)
        files["trajectory"] = "trajectory.npz"
    # Per cell, for surveyors' own tools: TD before, planned and executed deposit, residual, level.
    report.write_cells_csv(out / "cells.csv", report.cell_table(surface, plan, arm_plan.executed))
    files["cells"] = "cells.csv"
    write_cloud(out / "surface.ply", frame.cloud_to_input(surface.cloud),
                _core.point_td(surface.cloud, surface.axis, surface.profile))
    # The wall as the trajectory sprays it; the planner's estimate without a trajectory.
    sprayed = arm_plan.executed.sprayed_cloud if arm_plan.executed is not None else plan.sprayed_cloud
    write_cloud(out / "sprayed.ply", frame.cloud_to_input(sprayed), _core.point_td(sprayed, surface.axis, surface.profile))
    return files


def _save_npz(path: Path, **arrays) -> None:
    """np.savez_compressed at zlib level 1: the same file format (np.load reads it), half the time
    (float64 samples barely compress at any level: 42.8 MB against 43.1 at the default level 6)."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        for name, value in arrays.items():
            with z.open(name + ".npy", "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(value), allow_pickle=False)


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
