"""The generator's whole scene (issue 16): muck on the invert at the face and the scanner's shadow.

References are independent of the core's code: the muck's closed-form surface evaluated in numpy,
and the scanner's line of sight by marching each ray in 5 mm steps through the duct's and the
rig's solids (the core intersects the ray with the cylinder and the box analytically)."""
import json

import numpy as np
import pytest

import shotcrete


def scene_config(**synth):
    """A 1 rad crown slice, 0.6 m long, with 0.5 m of lining, the invert and the face."""
    cfg = shotcrete.load_config()
    s = cfg.synth
    s.theta_min_rad, s.theta_max_rad, s.length_m, s.points_per_cell = 1.0, 2.0, 0.6, 8
    s.context_enabled = True
    s.context_previous_bay_m = 0.5
    for k, v in synth.items():
        setattr(s, k, v)
    return cfg


def local(bay, xyz):
    """(d along the axis, y across, z up) of world points in the bay's frame."""
    a = bay.axis
    rel = np.asarray(xyz) - np.asarray(a.origin_m)
    return np.c_[rel @ np.asarray(a.ex), rel @ np.asarray(a.ey), rel @ np.asarray(a.ez)]


MUCK = dict(context_muck_height_m=0.8, context_muck_length_m=1.5, context_muck_width_m=3.0)


def test_muck_pile_lies_on_its_closed_form_surface():
    cfg = scene_config(**MUCK)
    bay = shotcrete.make_synthetic_bay(cfg.synth)
    s = cfg.synth
    h, L, W, H, end = s.context_invert_depth_m, 1.5, 3.0, 0.8, s.length_m

    def top(d, y):  # the documented shape, evaluated here
        u, v = (end - d) / L, 2 * y / W
        inside = (u >= 0) & (u <= 1) & (np.abs(v) <= 1)
        return np.where(inside, H * (1 - u) * (1 - v * v), 0.0)

    d, y = np.meshgrid(np.linspace(-1.5, 1.0, 41), np.linspace(-2.0, 2.0, 33))
    core = np.vectorize(bay.muck_height_at)(d, y)
    np.testing.assert_allclose(core, top(d, y), atol=1e-12)

    ctx = local(bay, shotcrete.make_synthetic_bay(cfg.synth).sample_context(0.05, 8, 0.0, 1).xyz)
    on_floor = np.abs(ctx[:, 2] + h) < 1e-9
    # The invert is not sampled under the pile, and the face not behind it.
    assert not np.any(on_floor & (top(ctx[:, 0], ctx[:, 1]) > 1e-9))
    face = np.abs(ctx[:, 0] - end) < 1e-9
    assert not np.any(face & (ctx[:, 2] < -h + top(end, ctx[:, 1]) - 1e-9))
    # The pile's points (noise-free here) lie on its surface, and as many as its area holds.
    muck = ~on_floor & ~face & (ctx[:, 2] < 0.0) & (ctx[:, 0] > end - L - 1e-9) & (np.abs(ctx[:, 1]) <= W / 2)
    np.testing.assert_allclose(ctx[muck, 2], -h + top(ctx[muck, 0], ctx[muck, 1]), atol=1e-9)
    # Area by the surface integral of sqrt(1 + |grad|^2) on a fine midpoint lattice.
    n = 600
    dd, yy = np.meshgrid(end - L + (np.arange(n) + 0.5) * L / n, -W / 2 + (np.arange(n) + 0.5) * W / n)
    u, v = (end - dd) / L, 2 * yy / W
    gd, gy = H / L * (1 - v * v), -H * (1 - u) * 4 * v / W
    area = np.sum(np.sqrt(1 + gd ** 2 + gy ** 2)) * (L / n) * (W / n)
    expected = area * 8 / 0.05 ** 2
    assert muck.sum() == pytest.approx(expected, rel=0.03)


def test_muck_stays_out_of_the_grid_and_in_the_obstacle_cloud():
    """The surface stage grids the same cells with and without the pile; its points stay in the
    surface's cloud (the clearance's wall), none of them gridded."""
    plain, muck = scene_config(), scene_config(**MUCK)
    surfaces = {}
    for name, cfg in (("plain", plain), ("muck", muck)):
        surfaces[name] = shotcrete.build_surface(shotcrete.make_synthetic_bay(cfg.synth).sample_scan(), cfg)
    a, b = surfaces["plain"].grid, surfaces["muck"].grid
    # The bay's rows of both grids (a few invert points at the face's foot, where the face and the
    # invert meet, may widen a scene's grid across: a known limit of the slice, see the docs).
    off = int(round((a.theta0_rad - b.theta0_rad) / a.dtheta_rad))
    assert a.n_d == b.n_d and 0 <= off and off + a.n_theta <= b.n_theta
    va, vb = np.asarray(a.valid), np.asarray(b.valid)
    np.testing.assert_array_equal(vb[off:off + a.n_theta], va)
    # The same points; the preprocessing's float32 shift and filters see a wider scene: within 1 mm.
    tdb, tda = np.asarray(b.td_m)[off:off + a.n_theta][va], np.asarray(a.td_m)[va]
    np.testing.assert_allclose(tdb, tda, atol=1e-3)
    assert np.mean(np.abs(tdb - tda)) < 1e-4
    assert vb.sum() - va.sum() <= 5
    s = surfaces["muck"]
    bay = shotcrete.make_synthetic_bay(muck.synth)
    pts = local(bay, s.cloud.xyz)
    h = muck.synth.context_invert_depth_m
    height = np.vectorize(bay.muck_height_at)(pts[:, 0], pts[:, 1])
    on_pile = (height > 0.05) & (np.abs(pts[:, 2] - (-h + height)) < 0.03)
    assert on_pile.sum() > 1000
    assert not np.asarray(s.in_grid)[on_pile].any()
    # The pile's crest at the face is in the cloud the clearance sees: a point within 5 cm of it.
    crest = np.array([muck.synth.length_m - 0.05, 0.0, -h + bay.muck_height_at(muck.synth.length_m - 0.05, 0.0)])
    assert np.min(np.linalg.norm(pts - crest, axis=1)) < 0.05


SHADOW = dict(context_duct_diameter_m=1.2, context_rig_length_m=4.0, context_scanner_shadow=True)


def march_visible(q, scanner, duct_c, duct_a, d_span, rig_lo, rig_hi, tol=0.03, step=0.005):
    """Line of sight by marching: the ray is blocked when, more than tol short of the point, it
    crosses the duct's round (a tube: the sign of the distance to its axis less its radius flips
    between two samples within its chainage) or a sample lies inside the rig's box."""
    out = np.ones(len(q), dtype=bool)
    for i, p in enumerate(q):
        v = p - scanner
        L = np.linalg.norm(v)
        t = np.arange(0.0, L - tol, step) / L
        x = scanner + t[:, None] * v
        side = np.hypot(x[:, 1] - duct_c[0], x[:, 2] - duct_c[1]) < duct_a
        within = (x[:, 0] >= d_span[0]) & (x[:, 0] <= d_span[1])
        crosses = (side[1:] != side[:-1]) & within[1:] & within[:-1]
        in_rig = np.all((x > rig_lo) & (x < rig_hi), axis=1)
        out[i] = not (crosses.any() or in_rig.any())
    return out


def test_scanner_shadow_matches_a_marched_line_of_sight():
    cfg = scene_config(**SHADOW)
    s = cfg.synth
    bay = shotcrete.make_synthetic_bay(cfg.synth)
    seen = shotcrete.make_synthetic_bay(scene_config(**{**SHADOW, "context_scanner_shadow": False}).synth)
    everything = np.asarray(seen.sample_scan().xyz)
    rng = np.random.default_rng(5)
    pick = everything[rng.choice(len(everything), 3000, replace=False)]
    R, a = s.design_radius_m, s.context_duct_diameter_m / 2
    zc = R - s.context_duct_gap_m - a
    h = s.context_invert_depth_m
    rig_lo = np.array([s.context_rig_front_d_m - s.context_rig_length_m, -s.context_rig_width_m / 2, -h])
    rig_hi = np.array([s.context_rig_front_d_m, s.context_rig_width_m / 2, -h + s.context_rig_height_m])
    ref = march_visible(local(bay, pick), np.asarray(s.context_scanner_position_m), (s.context_duct_y_m, zc), a,
                        (-s.context_previous_bay_m, s.length_m), rig_lo, rig_hi)
    core = np.array([bay.scanner_sees(p) for p in pick])
    # The two differ only on grazing rays (a 5 mm march step at the silhouette).
    assert np.mean(core == ref) > 0.995
    assert 0.05 < 1 - ref.mean() < 0.6  # the duct's back, the wall behind it, the rig's far sides
    # sample_scan drops exactly the points scanner_sees rejects: the same stream, filtered.
    kept = np.asarray(bay.sample_scan().xyz)
    mask = np.array([bay.scanner_sees(p) for p in everything])
    np.testing.assert_array_equal(kept, everything[mask])


def test_the_duct_ends_at_its_outlet():
    """synth.context_duct_outlet_d_m: the duct hangs from the lined bay's start to its outlet. Its
    points (within three noise sigmas of its round) all lie short of the outlet, and some reach it;
    the scanner's shadow is the marched line of sight through the shorter tube; the bay's crown
    under where the duct would have run is scanned. An outlet before the lining's start is refused,
    naming the key."""
    outlet = -0.2
    cfg = scene_config(**{**SHADOW, "context_duct_outlet_d_m": outlet})
    s = cfg.synth
    bay = shotcrete.make_synthetic_bay(s)
    R, a = s.design_radius_m, s.context_duct_diameter_m / 2
    zc = R - s.context_duct_gap_m - a
    seen = shotcrete.make_synthetic_bay(scene_config(**{**SHADOW, "context_duct_outlet_d_m": outlet,
                                                        "context_scanner_shadow": False}).synth)
    everything = np.asarray(seen.sample_scan().xyz)
    q = local(bay, everything)
    on_duct = (np.abs(np.hypot(q[:, 1] - s.context_duct_y_m, q[:, 2] - zc) - a) < 3 * s.noise_m) & \
        (q[:, 0] < s.length_m - 3 * s.noise_m)  # not the face across the duct's round
    assert on_duct.sum() > 100
    assert q[on_duct, 0].max() <= outlet + 3 * s.noise_m and q[on_duct, 0].max() > outlet - 0.05
    assert q[on_duct, 0].min() < -s.context_previous_bay_m + 0.05
    rng = np.random.default_rng(6)
    pick = everything[rng.choice(len(everything), 3000, replace=False)]
    h = s.context_invert_depth_m
    rig_lo = np.array([s.context_rig_front_d_m - s.context_rig_length_m, -s.context_rig_width_m / 2, -h])
    rig_hi = np.array([s.context_rig_front_d_m, s.context_rig_width_m / 2, -h + s.context_rig_height_m])
    ref = march_visible(local(bay, pick), np.asarray(s.context_scanner_position_m), (s.context_duct_y_m, zc), a,
                        (-s.context_previous_bay_m, outlet), rig_lo, rig_hi)
    core = np.array([bay.scanner_sees(p) for p in pick])
    assert np.mean(core == ref) > 0.995
    # The crown at the bay's far end (d > 0.45, within 0.3 m of the top) is seen past the shorter duct; over
    # both bays the duct hides most of it.
    crown = local(bay, np.asarray(bay.sample_scan().xyz))
    top = (crown[:, 0] > 0.45) & (np.hypot(crown[:, 1], crown[:, 2]) > R - 0.05) & (np.abs(crown[:, 1]) < 0.3)
    full = shotcrete.make_synthetic_bay(scene_config(**SHADOW).synth)
    crown_full = local(full, np.asarray(full.sample_scan().xyz))
    top_full = (crown_full[:, 0] > 0.45) & (np.hypot(crown_full[:, 1], crown_full[:, 2]) > R - 0.05) & \
        (np.abs(crown_full[:, 1]) < 0.3)
    assert top.sum() > 50 and top_full.sum() < 0.2 * top.sum()
    with pytest.raises(ValueError, match="context_duct_outlet_d_m"):
        shotcrete.make_synthetic_bay(scene_config(context_duct_diameter_m=1.2, context_duct_outlet_d_m=-0.6).synth).sample_scan()


def test_shadowed_scene_leaves_holes_behind_the_duct(tmp_path, run_cli):
    """The wall behind the duct is not scanned: those cells are holes, neither graded nor sprayed,
    and report.json counts them; below half the grid the plan is refused as sparse_grid."""
    cfg = scene_config(**SHADOW)
    bay = shotcrete.make_synthetic_bay(cfg.synth)
    surface = shotcrete.build_surface(bay.sample_scan(), cfg)
    g = surface.grid
    valid = np.asarray(g.valid)
    # Cells whose wall centre the scanner cannot see (the reference line of sight) are holes.
    s = cfg.synth
    R, a = s.design_radius_m, s.context_duct_diameter_m / 2
    zc = R - s.context_duct_gap_m - a
    scanner = np.asarray(s.context_scanner_position_m)
    hidden_rows = []
    for row in range(g.n_theta):
        th = g.theta0_rad + (row + 0.5) * g.dtheta_rad
        p = np.array([0.3, (R + 0.15) * np.cos(th), (R + 0.15) * np.sin(th)])
        # The ray from the scanner to the wall at d = 0.3 m, against the duct's circle in (y, z).
        v = p - scanner
        f = scanner[1:] - np.array([0.0, zc])
        A, B, C = v[1:] @ v[1:], 2 * f @ v[1:], f @ f - a * a
        disc = B * B - 4 * A * C
        if disc > 0 and 0 < (-B - np.sqrt(disc)) / (2 * A) < 1:
            hidden_rows.append(row)
    assert len(hidden_rows) >= 5
    col = int(round((0.3 - g.d0_m) / g.cell_size_m - 0.5))
    inner = hidden_rows[1:-1]  # rows at the silhouette may catch a point or two
    assert not valid[inner, col].any()
    assert valid.sum() < 0.9 * valid.size
    xyz = tmp_path / "scene.ply"
    shotcrete.write_cloud(xyz, bay.sample_scan())
    conf = tmp_path / "c.yaml"
    conf.write_text("synth:\n  theta_min_rad: 1.0\n  theta_max_rad: 2.0\n  length_m: 0.6\n"
                    "planner:\n  max_rounds: 1\nclearance:\n  enabled: false\n")
    r = run_cli("plan", xyz, "--out", tmp_path / "o", "--config", conf, "--json")
    assert r.exit_code in (0, 3), r.output
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    n_t, n_d = rep["grid_shape"]
    assert rep["holes"] == n_t * n_d - rep["cells"] and rep["holes"] >= len(inner) * n_d - n_d
    # Holes carry no level and no residual: cells.csv lists only cells with data.
    rows = (tmp_path / "o" / "cells.csv").read_text().splitlines()
    assert len(rows) - 1 == rep["cells"]


def nozzle_distance(tip, z, pts, radius=0.05, length=0.5):
    """Brute force: distance of every point to the nozzle link, a cylinder of `radius` from the tip
    back `length` along the spray axis z (the bundled URDF's nozzle link, rigid with the tip)."""
    v = pts - tip
    a = v @ z
    r = np.linalg.norm(v - np.outer(a, z), axis=1)
    excess = np.where(a > 0, a, np.where(a < -length, -length - a, 0.0))
    return np.hypot(np.maximum(r - radius, 0.0), excess)


def face_scene_obstruction(length_m=0.6, **clearance):
    """The 1 rad slice with the face at its end (no lining, no invert, no noise), its surface, its
    obstructed_cells with the clearance keys given, and the obstacle points (outside the grid)."""
    cfg = scene_config(context_previous_bay_m=0.0, context_invert_depth_m=0.0, noise_m=0.0, length_m=length_m)
    for k, v in clearance.items():
        setattr(cfg.clearance, k, v)
    surface = shotcrete.build_surface(shotcrete.make_synthetic_bay(cfg.synth).sample_scan(), cfg)
    ob = shotcrete._core.obstructed_cells(surface, shotcrete.load_robot(cfg), cfg)
    return cfg, surface, ob, np.asarray(surface.cloud.xyz)[~np.asarray(surface.in_grid)]


def grid_wall_points(g, cfg):
    """(row, col, d, radial unit z, wall point at the cell's TD) of every valid cell of a circle
    bay on the x axis."""
    valid, td = np.asarray(g.valid), np.asarray(g.td_m)
    for row in range(g.n_theta):
        th = g.theta0_rad + (row + 0.5) * g.dtheta_rad
        z = np.array([0.0, np.cos(th), np.sin(th)])
        for col in range(g.n_d):
            if valid[row, col]:
                d = g.d0_m + (col + 0.5) * g.cell_size_m
                yield row, col, d, z, np.array([d, 0, 0]) + (cfg.profile.design_radius_m + td[row, col]) * z


def test_obstructed_cells_by_the_face_match_a_brute_force_and_the_plane_distance():
    """A bay with the face at its end and the nozzle held square (max_nozzle_lean_rad 0): the cells
    whose spraying pose puts the nozzle within its margin (0.4 m) of the face are the obstructed
    ones; by the plane, d_face - d - 0.05 < 0.4."""
    cfg, surface, ob, pts = face_scene_obstruction(max_nozzle_lean_rad=0.0)
    assert ob.links == ["nozzle"] and ob.margin_m == cfg.clearance.nozzle_margin_m
    assert ob.obstacle_points == len(pts)
    g = surface.grid
    ref, plane = [], []
    for row, col, d, z, wall in grid_wall_points(g, cfg):
        if nozzle_distance(wall - cfg.planner.standoff_m * z, z, pts).min() < ob.margin_m:
            ref.append(row * g.n_d + col)
        if cfg.synth.length_m - d - 0.05 < ob.margin_m:
            plane.append(row * g.n_d + col)
    assert sorted(ob.cells) == ref == plane
    assert len(ref) > 0 and len(ref) < np.asarray(g.valid).sum()
    assert ob.leaned_cells == 0 and len(ob.lean) == 0


def leaned_axis(z, lean):
    """The spray axis z tipped toward the tangent vector `lean` by its length [rad]."""
    t = lean - (lean @ z) * z
    a = np.linalg.norm(t)
    return z if a < 1e-12 else np.cos(a) * z + np.sin(a) * t / a


def test_a_leaning_nozzle_clears_the_face_and_never_runs_back():
    """The same bay with the nozzle free to lean (default max_nozzle_lean_rad): no cell is
    obstructed; every cell's leaned pose keeps the nozzle link (brute force over the obstacle
    points) its margin from the face, leans toward the face and no further than allowed, the
    cells far from the face stay square, the last column's poses keep the margin after the passes'
    run-on there (planner.leaned_edge_overrun_m), and along each row the nozzle's place moves forward
    with the cell (the lean fades at clearance.nozzle_lean_fade_rad_per_m, 0.5 rad/m: at a 1 m
    standoff, half the spot's speed or more)."""
    cfg, surface, ob, pts = face_scene_obstruction(length_m=2.0)
    g = surface.grid
    valid = np.asarray(g.valid)
    assert ob.cells == [] and ob.leaned_cells > 0
    lean = np.asarray(ob.lean).reshape(g.n_theta, g.n_d, 3)
    angle = np.linalg.norm(lean, axis=2)
    assert angle.max() <= cfg.clearance.max_nozzle_lean_rad + 1e-9
    assert abs(ob.max_lean_rad - angle[valid].max()) < 1e-9
    assert ob.leaned_cells == int((valid & (angle > 1e-9)).sum())
    S, margin, face = cfg.planner.standoff_m, ob.margin_m, cfg.synth.length_m
    tips = np.full((g.n_theta, g.n_d), np.nan)
    square_seen = 0
    for row, col, d, z, wall in grid_wall_points(g, cfg):
        a = leaned_axis(z, lean[row, col])
        tip = wall - S * a
        assert nozzle_distance(tip, a, pts).min() >= margin
        if col == g.n_d - 1:  # the passes' run-on at the leaning end, the lean held
            run_on = np.array([min(cfg.planner.edge_overrun_m, cfg.planner.leaned_edge_overrun_m), 0.0, 0.0])
            assert nozzle_distance(tip + run_on, a, pts).min() >= margin
        tips[row, col] = tip[0]
        if angle[row, col] > 0:
            assert lean[row, col] @ np.array([1.0, 0, 0]) > 0.99 * angle[row, col]  # toward the face
        # Square where even the steepest needed lean (at a column blocked square) has faded.
        first_blocked = face - 0.05 - margin
        if d < first_blocked - ob.max_lean_rad / cfg.clearance.nozzle_lean_fade_rad_per_m - 0.05:
            assert angle[row, col] == 0.0
            square_seen += 1
    assert square_seen > 0.1 * valid.sum()  # the 2 m bay's first columns
    for row in range(g.n_theta):
        steps = np.diff(tips[row][valid[row]])
        assert (steps >= (1 - cfg.clearance.nozzle_lean_fade_rad_per_m * S) * g.cell_size_m - 1e-3).all()
    # A fade at or above 1 / standoff would run the nozzle back: refused, naming the key.
    cfg.clearance.nozzle_lean_fade_rad_per_m = 1.0 / S
    with pytest.raises(ValueError, match="nozzle_lean_fade_rad_per_m"):
        shotcrete._core.obstructed_cells(surface, shotcrete.load_robot(cfg), cfg)


def plan_face_scene(tmp_path, run_cli, extra_yaml="", place_base=False, base_position_m=None, synth_extra=None):
    """`shotcrete plan` (one round) on the face scene written as PLY: the config, the CLI result and
    report.json (out dir tmp_path / "o"). The base stays at robot.base_position_m (by default in the
    face's plane) unless ``place_base``. ``synth_extra``: more of the scene (synth.context_*)."""
    synth = {"context_previous_bay_m": 0.0, "context_invert_depth_m": 0.0, "noise_m": 0.0, **(synth_extra or {})}
    cfg = scene_config(**synth)
    xyz = tmp_path / "scene.ply"
    shotcrete.write_cloud(xyz, shotcrete.make_synthetic_bay(cfg.synth).sample_scan())
    conf = tmp_path / "c.yaml"
    conf.write_text("synth:\n  theta_min_rad: 1.0\n  theta_max_rad: 2.0\n  length_m: 0.6\n"
                    "planner:\n  max_rounds: 1\n" + f"robot:\n  place_base: {str(place_base).lower()}\n" +
                    (f"  base_position_m: {list(base_position_m)}\n" if base_position_m is not None else "") + extra_yaml)
    if base_position_m is not None:
        cfg.robot.base_position_m = base_position_m
    r = run_cli("plan", xyz, "--out", tmp_path / "o", "--config", conf, "--json")
    return cfg, r, json.loads((tmp_path / "o" / "report.json").read_text())


def test_plan_of_a_bay_against_its_face_leaves_the_obstructed_cells_out(tmp_path, run_cli):
    """The CLI on the face scene with the nozzle held square: exit 3 with obstructed_cells (and
    those cells not counted among the cells the plan left short); no pass puts the nozzle over
    them, so every pass waypoint keeps the nozzle's margin from the face (d <= d_face - margin -
    the nozzle's radius)."""
    cfg, r, rep = plan_face_scene(tmp_path, run_cli, "clearance:\n  max_nozzle_lean_rad: 0\n")
    assert r.exit_code == 3, r.output
    codes = [p["code"] for p in rep["problems"]]
    assert "obstructed_cells" in codes
    ob = rep["obstructed"]
    n_t, n_d = rep["grid_shape"]
    cols = {c % n_d for c in ob["cell_ids"]}
    d0 = rep["bay"]["start_m"]
    # The plane's reference: the columns whose centre lies past d_face - margin - 0.05 m.
    face_d, margin = cfg.synth.length_m, cfg.clearance.nozzle_margin_m
    assert cols == {c for c in range(n_d) if face_d - (d0 + (c + 0.5) * 0.05) - 0.05 < margin}
    plan = json.loads((tmp_path / "o" / "plan.json").read_text())
    ds = [w[0] for rnd in plan["rounds"] for reg in rnd["regions"] for p in reg["passes"] for w in p["positions_m"]]
    assert ds and max(ds) <= face_d - margin - 0.05 + 1e-4


def test_plan_of_a_bay_against_its_face_leans_the_nozzle_to_spray_it_all(tmp_path, run_cli):
    """The CLI on the same face scene with the nozzle free to lean: no cell is obstructed, the
    passes lean toward the face near it, and every waypoint (position and spray axis from
    plan.json) keeps the nozzle link, a 0.05 m cylinder 0.5 m back from the tip, its margin from
    the face plane; the cells by the face get concrete (the executed deposit, cells.csv)."""
    cfg, r, rep = plan_face_scene(tmp_path, run_cli)
    assert r.exit_code in (0, 3), r.output
    assert "obstructed_cells" not in [p["code"] for p in rep["problems"]]
    assert rep["obstructed"]["cells"] == 0 and rep["obstructed"]["leaned_cells"] > 0
    assert 0 < rep["obstructed"]["max_lean_deg"] <= np.degrees(cfg.clearance.max_nozzle_lean_rad) + 1e-6
    plan = json.loads((tmp_path / "o" / "plan.json").read_text())
    pos = np.array([w for rnd in plan["rounds"] for reg in rnd["regions"] for p in reg["passes"] for w in p["positions_m"]])
    ax = np.array([w for rnd in plan["rounds"] for reg in rnd["regions"] for p in reg["passes"] for w in p["axes"]])
    assert len(pos) == len(ax) > 0
    face_d, margin = cfg.synth.length_m, cfg.clearance.nozzle_margin_m
    link_front = pos[:, 0] + 0.05 * np.sqrt(np.clip(1 - ax[:, 0] ** 2, 0, 1))
    assert (face_d - link_front).min() >= margin - 1e-3
    assert ax[:, 0].max() > np.sin(0.3)  # leaned toward the face somewhere
    # The joins at the face's end keep the margin too: a pass end there is tight (its lean leaves
    # room for the run-on only), and the nozzle stops within v^2 / a of it and creeps across
    # instead of turning around 0.2 m further on (it came 0.17 m inside the margin).
    tr = np.load(tmp_path / "o" / "trajectory.npz")
    kind, tip, tax = tr["segment_kind"], tr["nozzle_position_m"], tr["nozzle_axis"]
    joins = np.isin(kind, [int(shotcrete._core.SegmentKind.TURN), int(shotcrete._core.SegmentKind.LINK)])
    assert joins.any()
    join_front = tip[joins, 0] + 0.05 * np.sqrt(np.clip(1 - tax[joins, 0] ** 2, 0, 1))
    assert (face_d - join_front).min() >= margin - 0.03
    cells = np.genfromtxt(tmp_path / "o" / "cells.csv", delimiter=",", names=True)
    last = cells["d_m"] > face_d - 0.05
    assert last.any() and (cells["deposit_executed_mm"][last] > 5).all()
    # The trajectory starts where report.json says; here the base stands at the face's plane (the
    # boom's root within its margin at every slew), so no posture is clear: the stow posture
    # stays, and a warning says so.
    start = rep["start_posture"]
    q0 = np.load(tmp_path / "o" / "trajectory.npz")["q"][0]
    assert np.allclose(q0, list(start["joints"].values()))
    assert not start["moved_from_stow"] and start["joints"] == start["stow"]
    assert start["stow_allowance_m"] < 0 and start["allowance_m"] < 0
    assert any("no posture clear of it was found" in w for w in rep["warnings"])
    # The turret (slewing about its own axis: no joint moves it) is in the face: the base's place
    # is the problem, named as such and kept out of the moving links' count.
    links = {l["link"]: l for l in rep["clearance"]["links"]}
    assert links["turret"]["fixed"] and links["turret"]["samples_below_margin"] > 0 and not links["boom"]["fixed"]
    assert links["turret"]["margin_m"] == cfg.clearance.base_margin_m and links["boom"]["margin_m"] == cfg.clearance.link_margin_m
    base = next(p for p in rep["problems"] if p["code"] == "base_clearance")
    assert "turret" in base["message"] and "robot.base_position_m" in base["message"]
    moving = sum(l["samples_below_margin"] for l in links.values() if not l["fixed"])
    clearance = next(p for p in rep["problems"] if p["code"] == "clearance")
    assert f"at {moving + rep['clearance']['self']['samples_below_margin']} link-samples" in clearance["message"]
    assert "turret" not in clearance["message"]


def test_the_job_places_the_base_back_from_the_face_where_the_arm_can_turn(tmp_path, run_cli):
    """The same face scene with robot.place_base (the default) and the base 0.4 m from the face (its
    base_link, 0.4 m in radius, touching it): the job moves it back along the axis, in 0.1 m steps,
    to where its fixed links keep base_margin_m and the arm has via_allowance_m of room at every
    slew direction. Closed form: at slew 0 the boom's root (its lift pivot, 0.3 m ahead of the slew
    axis, on the boom's shape) is no further than d_face - x_base - 0.3 from the face, so the base
    must stand at least 0.3 + link_margin_m + via_allowance_m (less 1 cm of slack) from it. The
    trajectory is the placed arm's (forward kinematics of trajectory.npz's joints at report.json's
    base give its nozzle positions), no base_clearance problem, and a warning names the move."""
    cfg, r, rep = plan_face_scene(tmp_path, run_cli, place_base=True, base_position_m=[0.2, 0.0, -1.2])
    assert r.exit_code in (0, 3), r.output
    b = rep["base_placement"]
    assert b["moved"] and b["found"] and b["shift_m"] < 0
    assert abs(b["shift_m"] / 0.1 - round(b["shift_m"] / 0.1)) < 1e-9
    conf_base = np.asarray(cfg.robot.base_position_m)
    assert np.allclose(b["configured_m"], conf_base)
    assert np.allclose(b["position_m"], conf_base + [b["shift_m"], 0, 0])
    face_d, c = cfg.synth.length_m, cfg.clearance
    assert face_d - b["position_m"][0] >= 0.3 + c.link_margin_m + c.via_allowance_m - 0.01 - 1e-9
    assert b["configured_room_m"] < c.via_allowance_m - 0.01 <= b["room_m"] and b["base_room_m"] >= 0
    assert any("the base is placed" in w and "back along the axis" in w for w in rep["warnings"])
    page = (tmp_path / "o" / "report.html").read_text()
    assert 'id="base-placement"' in page and f"{abs(b['shift_m']):.1f} m back" in page
    assert "base_clearance" not in [p["code"] for p in rep["problems"]]
    links = {l["link"]: l for l in rep["clearance"]["links"]}
    assert links["turret"]["samples_below_margin"] == 0 and links["base_link"]["samples_below_margin"] == 0
    tr = np.load(tmp_path / "o" / "trajectory.npz")
    assert np.allclose(tr["base_position_m"], b["position_m"])
    robot = shotcrete.load_robot(cfg).placed_at(np.asarray(b["position_m"]))
    for k in range(0, len(tr["q"]), max(1, len(tr["q"]) // 50)):
        assert np.allclose(np.asarray(robot.fk(tr["q"][k]))[:3, 3], tr["nozzle_position_m"][k], atol=1e-6)
    # The arm can run what the report says: every joint within its velocity and acceleration
    # limits by central differences of trajectory.npz's times and joints (what the timing left over
    # a limit is slowed to it: report.json says how much, and how far over it was).
    t, q = tr["t_s"], tr["q"]
    h1, h2 = np.diff(t)[:-1, None], np.diff(t)[1:, None]
    d1, d2 = (q[1:-1] - q[:-2]) / h1, (q[2:] - q[1:-1]) / h2
    qd, qdd = (h2 * d1 + h1 * d2) / (h1 + h2), 2 * (d2 - d1) / (h1 + h2)
    assert (np.abs(qd) / np.asarray(robot.velocity_limits)).max() <= 1.0 + 1e-6
    assert (np.abs(qdd) / np.asarray(robot.acceleration_limits)).max() <= 1.0 + 1e-6
    slowed = rep["trajectory"]["slowed_to_joint_limits"]
    assert slowed["ratio_before"] >= max(rep["trajectory"]["max_velocity_ratio"], rep["trajectory"]["max_acceleration_ratio"]) - 1e-9
    assert (slowed["added_s"] > 0) == (slowed["ratio_before"] > 1.0) and (slowed["intervals"] > 0) == (slowed["added_s"] > 0)
    assert 0 <= slowed["spraying_s"] <= slowed["added_s"]
    assert "joint_limits" not in [p["code"] for p in rep["problems"]]
    # Said where a site engineer reads it: a warning and the report page's note, or neither.
    warned = [w for w in rep["warnings"] if "slowed to it" in w]
    assert len(warned) == (1 if slowed["added_s"] > 0 else 0)
    assert ('id="slowed"' in page) == (slowed["added_s"] > 0)


def carrier_box_in_base(urdf_path):
    """The URDF's carrier link (fixed to base_link): its box's (lo, hi) corners in base_link's frame,
    read with ElementTree (not the core's loader)."""
    import xml.etree.ElementTree as ET
    root = ET.parse(urdf_path).getroot()
    joint = next(j for j in root.findall("joint") if j.find("child").get("link") == "carrier")
    assert joint.get("type") == "fixed" and joint.find("parent").get("link") == "base_link"
    at = np.array([float(v) for v in joint.find("origin").get("xyz").split()])
    col = root.find("link[@name='carrier']").find("collision")
    centre = at + np.array([float(v) for v in col.find("origin").get("xyz").split()])
    size = np.array([float(v) for v in col.find("geometry").find("box").get("size").split()])
    return centre - size / 2, centre + size / 2


def test_the_rigs_carrier_in_the_scan_is_the_machines_own_and_moves_with_the_base(tmp_path, run_cli):
    """The face scene with the invert and the rig's carrier standing where the URDF's carrier link
    is (1 m behind the base), the base 0.4 m from the face: the scan's points in the carrier's
    column up to its top (within clearance.carrier_tolerance_m) are the machine's own, counted in
    report.json clearance.carrier_points as a column test on the job's own cloud with the box read
    from the URDF file (and returned as bool arrays by the bindings); they are not obstacles, so the job places the base back from the face
    as in the scene without the rig (the closed form of the face test), the carrier moving with it
    (the carrier link keeps its margin at every sample)."""
    base = [0.2, 0.0, -1.2]
    lo, hi = carrier_box_in_base(shotcrete.robot.urdf_path())
    ground = base[2] - 0.3  # the generator's invert (context_invert_depth_m 1.5 below the axis)
    cfg, r, rep = plan_face_scene(tmp_path, run_cli, place_base=True, base_position_m=base, synth_extra={
        "context_invert_depth_m": -ground, "context_rig_length_m": float(hi[0] - lo[0]),
        "context_rig_width_m": float(hi[1] - lo[1]), "context_rig_height_m": float(base[2] + hi[2] - ground),
        "context_rig_front_d_m": base[0] + float(hi[0])})
    assert r.exit_code in (0, 3), r.output
    b = rep["base_placement"]
    # The reference: the job's cloud (the surface stage's, as the job builds it) in the column.
    surface = shotcrete.build_surface(shotcrete.read_cloud(tmp_path / "scene.ply"), cfg)
    p = np.asarray(surface.cloud.xyz) - np.asarray(base)
    tol = cfg.clearance.carrier_tolerance_m
    column = ((p[:, 0] >= lo[0] - tol) & (p[:, 0] <= hi[0] + tol) & (p[:, 1] >= lo[1] - tol) & (p[:, 1] <= hi[1] + tol)
              & (p[:, 2] <= hi[2] + tol) & ~np.asarray(surface.in_grid))
    assert column.sum() > 1000  # the rig's top and sides, the invert under it
    assert rep["clearance"]["carrier_points"] == int(column.sum())
    robot = shotcrete.load_robot(cfg)
    assert np.array_equal(shotcrete._core.scan_machine_points(surface, cfg, robot), column)
    assert np.array_equal(shotcrete._core.machine_points(np.asarray(surface.cloud.xyz), robot, tol), column)
    assert b["moved"] and b["found"] and b["shift_m"] < 0
    face_d, c = cfg.synth.length_m, cfg.clearance
    assert face_d - b["position_m"][0] >= 0.3 + c.link_margin_m + c.via_allowance_m - 0.01 - 1e-9
    assert b["base_room_m"] >= 0
    assert "base_clearance" not in [q["code"] for q in rep["problems"]]
    links = {l["link"]: l for l in rep["clearance"]["links"]}
    assert links["carrier"]["fixed"] and links["carrier"]["samples_below_margin"] == 0
    assert links["carrier"]["min_m"] >= c.base_margin_m


def test_the_carrier_lies_along_a_turned_axis():
    """The scene with the rig, turned 30 deg about the vertical (the axis, the base and the scan
    together): the job turns the carrier along the axis (base_link has no heading of its own), so the
    same points are the machine's own as in the scene as generated, and the base is placed alike
    (the same shift); with the carrier as the URDF puts it (along base_link's -x) the column would
    cut across the tunnel and miss most of the rig."""
    cfg = scene_config(context_invert_depth_m=1.5, context_rig_length_m=4.0, context_rig_front_d_m=-0.8, noise_m=0.0)
    cfg.robot.base_position_m = [0.2, 0.0, -1.2]  # 0.4 m from the face: placed back
    cloud = shotcrete.make_synthetic_bay(cfg.synth).sample_scan()
    robot = shotcrete.load_robot(cfg)
    flat_surface = shotcrete.build_surface(cloud, cfg)
    flat = shotcrete._core.scan_machine_points(flat_surface, cfg, robot)
    assert flat.sum() > 1000
    a = np.radians(30.0)
    R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    turned_cfg = scene_config(context_invert_depth_m=1.5, context_rig_length_m=4.0, context_rig_front_d_m=-0.8, noise_m=0.0)
    turned_cfg.profile.axis_direction = (R @ [1.0, 0.0, 0.0]).tolist()
    turned_cfg.robot.base_position_m = (R @ np.asarray(cfg.robot.base_position_m)).tolist()
    turned_robot = shotcrete.load_robot(turned_cfg)
    surface = shotcrete.build_surface(shotcrete._core.Cloud(np.asarray(cloud.xyz) @ R.T), turned_cfg)
    turned = shotcrete._core.scan_machine_points(surface, turned_cfg, turned_robot)
    # The reference: the turned job's own cloud turned back, against the carrier as generated.
    back = np.asarray(surface.cloud.xyz) @ R
    ref = shotcrete._core.machine_points(back, robot, cfg.clearance.carrier_tolerance_m) & ~np.asarray(surface.in_grid)
    assert np.array_equal(turned, ref)
    assert abs(int(turned.sum()) - int(flat.sum())) < 0.02 * flat.sum()  # the same rig (the voxel filter is not turned)
    as_urdf = shotcrete._core.machine_points(np.asarray(surface.cloud.xyz), turned_robot, turned_cfg.clearance.carrier_tolerance_m)
    assert as_urdf.sum() < 0.7 * flat.sum()
    # The base is placed alike: the same shift along the axis (the carrier turned once, along it).
    flat_place = shotcrete._core.place_base(flat_surface, cfg, robot)
    turned_place = shotcrete._core.place_base(surface, turned_cfg, turned_robot)
    assert flat_place.found and flat_place.moved and turned_place.found
    assert turned_place.shift_m == pytest.approx(flat_place.shift_m)
    assert turned_place.base_room_m == pytest.approx(flat_place.base_room_m, abs=0.02)
