"""Transits by the seed method (issue 18): joint moves closer than the margins re-routed through a via
posture of maximum space allowance; checked here with exact numpy distances to the wall's points."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import shotcrete
from shape_distance import shape_distance
from shotcrete import _core

R = 4.5  # the narrow bay


def _region(theta0: float) -> list:
    """Two serpentine axial passes at 1 m standoff from the narrow wall, from angle theta0."""
    passes = []
    for i in range(2):
        th = theta0 + i * 0.2 / R
        xs = np.linspace(0.3, 0.9, 61)[:: 1 if i % 2 == 0 else -1]
        p = _core.Pass()
        p.waypoints = [_core.NozzlePose(np.array([x, (R - 1) * math.cos(th), (R - 1) * math.sin(th)]),
                                        np.array([0.0, math.cos(th), math.sin(th)])) for x in xs]
        p.speed_mps, p.length_m = 0.3, 0.6
        passes.append(p)
    return passes


def _wall(x_c: float, th_c: float, height: float, radius: float = 0.8) -> np.ndarray:
    """The narrow wall with a dome (the synthetic pits' shape) standing `height` toward the axis."""
    th, x = np.meshgrid((np.arange(353) + 0.5) * math.pi / 353, np.arange(-0.6, 2.0, 0.04) + 0.02)
    q = (((th - th_c) * R) ** 2 + (x - x_c) ** 2) / radius**2
    r = R - np.where(q < 1, height * np.clip(1 - q, 0, None) ** 1.5, 0.0)
    return np.column_stack([x.ravel(), (r * np.cos(th)).ravel(), (r * np.sin(th)).ravel()])


def _exact_allowance(robot, q, wall: np.ndarray, cfg) -> float:
    """Least distance less margin over every link shape (numpy, every wall point)."""
    frames = robot.link_frames(q)
    return min(shape_distance(s, frames[s.frame], wall) - _core.shape_margin_m(s, cfg) for s in robot.collision_shapes)


def test_a_transit_through_a_rock_is_rerouted_clear_by_exact_distances():
    cfg = shotcrete.load_config()
    robot = shotcrete.load_robot(cfg)
    tr = _core.time_plan(robot, [_region(0.55), _region(2.45)], robot.stow(), cfg.timing, cfg.robot, None)
    moves = _core.joint_moves(tr)
    start, end, region = next(m for m in moves[1:] if m[2] == -1)  # the transit between the regions
    nozzle = np.asarray(tr.positions)[start:end + 1]
    room = R - np.hypot(nozzle[:, 1], nozzle[:, 2])
    k = int(np.argmin(room))
    wall = _wall(nozzle[k, 0], math.atan2(nozzle[k, 2], nozzle[k, 1]), room[k] - cfg.clearance.nozzle_margin_m + 0.3)
    q = np.asarray(tr.joint_table())[:, 1:1 + robot.dof]
    assert min(_exact_allowance(robot, q[i], wall, cfg.clearance) for i in range(start, end + 1, 10)) < 0
    duration = tr.duration_s
    rep = _core.clear_transits(robot, tr, _core.WallOctree(wall, 0.05), cfg.clearance, cfg.timing)
    assert rep.failed == 0 and rep.rerouted >= 1 and rep.moves_checked == len(moves)
    assert moves.index((start, end, region)) in [d.move for d in rep.detours]
    assert math.isclose(rep.detour_time_s, sum(d.duration_s - d.straight_duration_s for d in rep.detours), abs_tol=1e-9)
    assert math.isclose(tr.duration_s, duration + rep.detour_time_s, abs_tol=1e-9)
    after = _core.joint_moves(tr)
    q = np.asarray(tr.joint_table())[:, 1:1 + robot.dof]
    for d in rep.detours:
        s, e, _ = after[d.move]
        exact = min(_exact_allowance(robot, q[i], wall, cfg.clearance) for i in range(s, e + 1))
        assert exact >= 0.0, (d.move, exact)
        assert d.min_allowance_m <= exact + 1e-6  # the octree reads short, never long
        assert d.vias and all(a >= 0 for a in d.via_allowance_m)


def test_a_move_no_via_route_clears_is_sampled_clear_by_exact_distances():
    """A rock 0.6 m into the nozzle's room over the crown: no via route clears the move from the stow
    posture; the sampled planner (joint-space RRT-Connect) finds one that keeps every margin at
    every sample by exact numpy distances to the wall's points; with it off, the move is not re-routed."""
    cfg = shotcrete.load_config()
    assert cfg.clearance.sampled_route_nodes > 0
    robot = shotcrete.load_robot(cfg)
    plan = [_region(0.55), _region(2.45)]
    tr = _core.time_plan(robot, plan, robot.stow(), cfg.timing, cfg.robot, None)
    moves = _core.joint_moves(tr)
    start, end, _ = next(m for m in moves[1:] if m[2] == -1)
    nozzle = np.asarray(tr.positions)[start:end + 1]
    room = R - np.hypot(nozzle[:, 1], nozzle[:, 2])
    k = int(np.argmin(room))
    wall = _wall(nozzle[k, 0], math.atan2(nozzle[k, 2], nozzle[k, 1]), room[k] - cfg.clearance.nozzle_margin_m + 0.6)
    octree = _core.WallOctree(wall, 0.05)
    s0, e0, _ = moves[0]
    q0 = np.asarray(tr.joint_table())[:, 1:1 + robot.dof]
    assert min(_exact_allowance(robot, q0[i], wall, cfg.clearance) for i in range(s0, e0 + 1, 10)) < 0  # straight: through it
    rep = _core.clear_transits(robot, tr, octree, cfg.clearance, cfg.timing)
    first = next(d for d in rep.detours if d.move == 0)
    assert first.rerouted and first.sampled_nodes > 0 and first.vias, first.reason
    s, e, _ = _core.joint_moves(tr)[0]
    q = np.asarray(tr.joint_table())[:, 1:1 + robot.dof]
    exact = min(_exact_allowance(robot, q[i], wall, cfg.clearance) for i in range(s, e + 1))
    assert exact >= 0.0 and first.min_allowance_m <= exact + 1e-6
    off = cfg.clearance
    off.sampled_route_nodes = 0
    plain = _core.time_plan(robot, plan, robot.stow(), cfg.timing, cfg.robot, None)
    kept = next(d for d in _core.clear_transits(robot, plain, octree, off, cfg.timing).detours if d.move == 0)
    assert not kept.rerouted and kept.sampled_nodes == 0


def test_report_json_has_the_transits_of_every_job(tmp_path):
    """The default config checks the joint moves of every job: report.json clearance.transits (a small
    bay whose moves are all clear: nothing re-routed, no time added)."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text("synth: {theta_min_rad: 1.0, theta_max_rad: 1.4, length_m: 0.6, points_per_cell: 6, pit_count: 2}\n")
    out = tmp_path / "o"
    r = subprocess.run([str(Path(sys.executable).parent / "shotcrete"), "demo", "--out", str(out), "--config", str(cfg)],
                       capture_output=True, text=True)
    report = json.loads((out / "report.json").read_text())
    t = report["clearance"]["transits"]
    assert t["checked"] >= 1  # at least the move from the stow posture
    assert (t["rerouted"], t["failed"], t["detours"], t["detour_time_s"]) == (0, 0, [], 0.0)
    assert report["clearance"]["samples_below_margin"] == 0 and r.returncode == 0, r.stderr


def test_timed_trajectory_from_joints_checks_as_the_timed_one():
    """TimedTrajectory.from_joints (a saved trajectory's times and joints): check_clearance reads the
    same as on the timed trajectory itself; mismatched or bad input is a clear error."""
    cfg = shotcrete.load_config()
    robot = shotcrete.load_robot(cfg)
    tr = _core.time_plan(robot, [_region(0.55), _region(2.45)], robot.stow(), cfg.timing, cfg.robot, None)
    saved = _core.TimedTrajectory.from_joints(np.asarray(tr.t_s).tolist(), np.asarray(tr.q))
    assert len(saved.t_s) == len(tr.t_s) and np.array_equal(np.asarray(saved.q), np.asarray(tr.q))
    wall = _core.WallOctree(_wall(0.6, 1.2, 0.3), 0.05)
    a = _core.check_clearance(robot, tr, wall, cfg.clearance)
    b = _core.check_clearance(robot, saved, wall, cfg.clearance)
    assert [(l.link, l.min_m, l.at_time_s, l.samples_below_margin) for l in a.links] == \
        [(l.link, l.min_m, l.at_time_s, l.samples_below_margin) for l in b.links]
    assert (a.field_queries, a.exact_queries, a.self_queries) == (b.field_queries, b.exact_queries, b.self_queries)
    q = np.asarray(tr.q)
    with pytest.raises(ValueError, match="times but"):
        _core.TimedTrajectory.from_joints([0.0, 1.0], q[:3])
    with pytest.raises(ValueError, match="non-decreasing"):
        _core.TimedTrajectory.from_joints([0.0, 2.0, 1.0], q[:3])
    bad = q[:3].copy()
    bad[1, 2] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        _core.TimedTrajectory.from_joints([0.0, 1.0, 2.0], bad)
    # Times and joints carry no sample kinds: finding the joint moves is refused, not read past the end.
    with pytest.raises(ValueError, match="sample kinds"):
        _core.clear_transits(robot, saved, wall, cfg.clearance, cfg.timing)
    with pytest.raises(ValueError, match="sample kinds"):
        _core.joint_moves(saved)


def _face(x_face: float) -> np.ndarray:
    """A face across the narrow bay at x = x_face, points every 4 cm above the springlines."""
    y, z = np.meshgrid(np.arange(-R, R, 0.04), np.arange(0.0, R, 0.04))
    inside = np.hypot(y, z) < R
    return np.column_stack([np.full(inside.sum(), x_face), y[inside], z[inside]])


def test_a_job_starts_from_the_stow_posture_or_the_nearest_clear_one():
    """start_posture: the stow posture when it keeps its margins (nothing searched); with a face
    1.4 m ahead of the base the stow posture's boom is in it (exact numpy distances), and the
    posture found keeps every margin by the same exact distances, within the joint limits, the
    octree's reading never more than the exact one."""
    cfg = shotcrete.load_config()
    robot = shotcrete.load_robot(cfg)
    wall = _wall(0.6, 1.2, 0.0)
    stow = np.asarray(robot.stow())
    assert _exact_allowance(robot, stow, wall, cfg.clearance) >= 0
    same = _core.start_posture(robot, stow, _core.WallOctree(wall, 0.05), cfg.clearance)
    assert not same.moved and np.array_equal(same.q, stow) and same.optimisations == 0
    closed = np.vstack([wall[wall[:, 0] < 2.0], _face(2.0)])
    assert _exact_allowance(robot, stow, closed, cfg.clearance) < 0
    sp = _core.start_posture(robot, stow, _core.WallOctree(closed, 0.05), cfg.clearance)
    assert sp.moved and sp.preferred_allowance_m < 0 <= sp.allowance_m
    exact = _exact_allowance(robot, sp.q, closed, cfg.clearance)
    assert exact >= 0 and sp.allowance_m <= exact + 1e-6
    lo, hi = np.asarray(robot.lower_limits), np.asarray(robot.upper_limits)
    assert np.all(sp.q >= lo) and np.all(sp.q <= hi)
    with pytest.raises(ValueError, match="does not match the robot"):
        _core.start_posture(robot, stow[:3], _core.WallOctree(closed, 0.05), cfg.clearance)


def test_plan_by_a_face_starts_clear_of_it_and_routes_the_first_move_around_it(tmp_path, run_cli):
    """`shotcrete plan` on a 1.5 m crown slice with its face (the stow posture's boom points into
    it): report.json start_posture says the job starts elsewhere, the trajectory's first sample is
    that posture, it keeps every margin from the scan's points (exact numpy distances), and the
    move from it is checked and re-routed clear, not refused."""
    conf = tmp_path / "c.yaml"
    conf.write_text("synth: {theta_min_rad: 1.45, theta_max_rad: 1.7, length_m: 1.5, points_per_cell: 4, pit_count: 2,"
                    " context_enabled: true, context_previous_bay_m: 0.0, context_invert_depth_m: 0.0}\n"
                    # The first round's plan as before its look-ahead took the wide lines: with the
                    # default, its first pass starts at a posture within the face's margin, which no
                    # route can help (the detour says so; README "A scan of the whole scene").
                    "planner: {max_rounds: 1, levelling_lookahead_late_lines: false, levelling_lookahead_rounds: 3}\n"
                    "timing: {max_replans: 0}\n"
                    # The base where configured, 0.9 m from the face (robot.place_base would move it
                    # back: tests/python/test_scene.py).
                    "robot: {place_base: false}\n")
    cfg = shotcrete.load_config(conf)
    scan = shotcrete.make_synthetic_bay(cfg.synth).sample_scan()
    shotcrete.write_cloud(tmp_path / "scene.ply", scan)
    r = run_cli("plan", tmp_path / "scene.ply", "--out", tmp_path / "o", "--config", conf)
    assert r.exit_code in (0, 3), r.output
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    robot = shotcrete.load_robot(cfg)
    pts = np.asarray(scan.xyz, dtype=float)
    start = rep["start_posture"]
    stow = np.asarray(robot.stow())
    assert np.allclose(list(start["stow"].values()), stow)
    assert _exact_allowance(robot, stow, pts, cfg.clearance) < 0 and start["stow_allowance_m"] < 0
    assert start["moved_from_stow"] and start["allowance_m"] >= 0
    q0 = np.load(tmp_path / "o" / "trajectory.npz")["q"][0]
    assert np.allclose(q0, list(start["joints"].values()))
    assert _exact_allowance(robot, q0, pts, cfg.clearance) >= 0
    assert any("the job starts from the nearest posture clear of it" in w for w in rep["warnings"])
    first = [d for d in rep["clearance"]["transits"]["detours"] if d["move"] == 0]
    assert len(first) == 1 and first[0]["rerouted"]  # the straight move from the start crosses the face


def test_fixed_shapes_are_those_no_joint_moves():
    """fixed_shapes against the shapes' own placement (numpy, link_frames): a cylinder's axis ends
    stay put over random postures for the fixed ones (base_link; the turret, slewing about its own
    axis) and move for every other; posture_allowance without them ignores a rock at the base."""
    cfg = shotcrete.load_config()
    robot = shotcrete.load_robot(cfg)
    fixed = _core.fixed_shapes(robot)
    rng = np.random.default_rng(3)
    lo, hi = np.asarray(robot.lower_limits), np.asarray(robot.upper_limits)

    def ends(q):
        frames = robot.link_frames(q)
        out = []
        for s in robot.collision_shapes:
            T = np.asarray(frames[s.frame]) @ np.asarray(s.origin)
            out.append(np.r_[T[:3, 3] - 0.5 * s.length_m * T[:3, 2], T[:3, 3] + 0.5 * s.length_m * T[:3, 2]])
        return np.array(out)

    ref = ends(robot.neutral())
    moved = np.zeros(len(fixed), bool)
    for _ in range(20):
        moved |= np.abs(ends(rng.uniform(lo, hi)) - ref).max(axis=1) > 1e-9
    assert list(~moved) == list(fixed)
    assert [s.link for s, f in zip(robot.collision_shapes, fixed) if f] == ["base_link", "turret", "carrier"]
    # A rock against the base: every posture breaks a margin, none does without the fixed shapes.
    base = np.asarray(cfg.robot.base_position_m)
    wall = np.vstack([_wall(0.6, 1.2, 0.0), base + [0.45, 0.0, 0.1]])
    octree = _core.WallOctree(wall, 0.05)
    stow = np.asarray(robot.stow())
    assert _core.posture_allowance(robot, stow, octree, cfg.clearance) < 0
    assert _core.posture_allowance(robot, stow, octree, cfg.clearance, without_fixed=True) >= 0
