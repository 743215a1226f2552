"""Planner through the Python API and the CLI report contract (docs/architecture.md §10)."""
import json

import numpy as np
import pytest

import shotcrete
from shotcrete import _core

SMALL_BAY = """
synth: {theta_min_rad: 1.0, theta_max_rad: 1.6, length_m: 1.2, points_per_cell: 6, pit_count: 5}
"""

REPORT_KEYS = {"cells", "levels_before", "levels_after", "residual_mm", "rounds", "passes", "spray_time_s",
               "total_time_s", "required_volume_m3", "physical_limit_s", "spray_time_ratio", "timings_s", "ik",
               "cycle_time_s", "cycle_time_breakdown_s", "cycle_time_ratio",
               "deposit_source", "planned_residual_mm", "planned_levels_after", "planned_vs_executed_mm", "executed"}


@pytest.fixture(scope="module")
def small():
    cfg = shotcrete.Config.from_yaml(SMALL_BAY)
    return cfg, shotcrete.synthetic_cloud(cfg)


@pytest.mark.parametrize("mode", ["graded", "optimal"])
def test_plan_api_finishes_the_bay(small, mode):
    cfg, cloud = small
    cfg = cfg.copy()
    cfg.planner.mode = mode
    stages = []
    plan = shotcrete.plan(cloud, cfg, lambda stage, f: stages.append(stage), arm=False)  # plan_bay
    assert isinstance(plan, shotcrete.Plan)
    assert plan.rounds and stages
    surface = shotcrete.build_surface(cloud, cfg)
    valid = np.asarray(surface.grid.valid).reshape(-1)
    td = np.asarray(plan.td_after_m)
    assert td.shape == valid.shape and td.dtype == np.float64
    assert max(shotcrete.level_of_td_mm(x * 1000) for x in td[valid]) <= 0
    # Speeds within the configured bounds, waypoints as (N, 3) arrays in metres.
    for rnd in plan.rounds:
        for reg in rnd.regions:
            for p in reg.passes:
                assert p.positions_m.shape == (len(p.waypoints), 3)
                v = p.speed_profile_mps or [p.speed_mps]
                assert cfg.planner.min_speed_mps - 1e-9 <= min(v) and max(v) <= cfg.planner.max_speed_mps + 1e-9
    # Mass balance: what the plan sprays (and stays) is what the wall gained, less spray beyond the scan.
    gained = np.sum((np.asarray(surface.grid.td_m).reshape(-1) - td)[valid]) * cfg.grid.cell_size_m ** 2
    sprayed = plan.spray_time_s * plan.deposition_rate_m3ps
    assert 0.75 * sprayed < gained <= 1.01 * sprayed


def test_optimal_beats_graded_on_residual(small):
    cfg, cloud = small
    rms = {}
    for mode in ("graded", "optimal"):
        c = cfg.copy()
        c.planner.mode = mode
        surface = shotcrete.build_surface(cloud, c)
        valid = np.asarray(surface.grid.valid).reshape(-1)
        r = np.asarray(shotcrete.plan_bay(surface, c).td_after_m)[valid]
        rms[mode] = float(np.sqrt(np.mean(r ** 2)))
    assert rms["optimal"] < rms["graded"]


def _leaves(node, prefix=""):
    if isinstance(node, dict):
        return {k: v for key, child in node.items() for k, v in _leaves(child, f"{prefix}{key}.").items()}
    if isinstance(node, list):
        return {k: v for i, child in enumerate(node) for k, v in _leaves(child, f"{prefix}{i}.").items()}
    return {prefix[:-1]: node}


def test_cli_demo_report_contract(tmp_path, run_cli):
    cfg = tmp_path / "small.yaml"
    cfg.write_text(SMALL_BAY)
    out = tmp_path / "demo"
    r = run_cli("demo", "--out", out, "--config", cfg, "--json")
    assert r.exit_code == 0, r.output
    report = json.loads((out / "report.json").read_text())
    assert REPORT_KEYS <= set(report)
    # report.json is the core's job summary (+ timings_s, files), and shotcrete.plan() plans as the
    # CLI does: for the arm.
    config = shotcrete.load_config(cfg)
    cloud = shotcrete.synthetic_cloud(config)
    job = shotcrete.plan(cloud, config)
    assert isinstance(job, shotcrete.ArmPlan) and job.trajectory is not None
    summary = shotcrete.summarise_job(shotcrete.build_surface(cloud, config), job, shotcrete.load_robot(config),
                                      config, points_in=len(cloud))
    expected = _leaves(summary.to_dict())
    got = _leaves({k: report[k] for k in summary.to_dict()})
    assert set(got) == set(expected)
    numbers = [k for k, v in expected.items() if isinstance(v, float)]
    assert {k: got[k] for k in numbers} == pytest.approx({k: expected[k] for k in numbers}, rel=1e-9)
    assert {k: got[k] for k in expected if k not in numbers} == {k: v for k, v in expected.items() if k not in numbers}
    assert set(report) - set(summary.to_dict()) == {"timings_s", "files", "provenance", "local_origin_m"}
    assert report["local_origin_m"] == [0.0, 0.0, 0.0]  # a bay near its own origin runs unshifted
    # The bay alone gives the arm room to slew every way where configured: the base stays.
    b = report["base_placement"]
    assert not b["moved"] and b["found"] and b["places_tried"] == 1 and b["shift_m"] == 0.0
    assert b["position_m"] == b["configured_m"] == list(config.robot.base_position_m)
    assert b["room_m"] >= config.clearance.via_allowance_m - 0.01 and b["base_room_m"] >= 0
    assert not any("base is placed" in w or "the base stays" in w for w in report["warnings"])
    assert summary.passes == report["passes"]
    assert summary.trajectory.duration_s == pytest.approx(report["total_time_s"], rel=1e-9)
    assert set(report["residual_mm"]) >= {"mean", "min", "max", "rms"}
    assert report["ik"]["solved"] and report["ik"]["worst_position_error_m"] < 1e-3
    assert report["total_time_s"] >= report["spray_time_s"] > 0
    assert report["spray_time_ratio"] == pytest.approx(report["spray_time_s"] / report["physical_limit_s"])
    plan = json.loads((out / "plan.json").read_text())
    first = plan["rounds"][0]["regions"][0]["passes"][0]
    assert len(first["positions_m"][0]) == 3 and first["speed_mps"] > 0
    traj = np.load(out / "trajectory.npz")
    assert traj["q"].shape[1] == 8 and len(traj["t_s"]) == len(traj["q"])
    _check_cycle_time(report, traj, config)
    html = (out / "report.html").read_text()
    for src in [s.split('"')[0] for s in html.split('src="')[1:]]:
        assert (out / src).is_file(), src
    assert "Round 1" in html


def test_bad_planner_config_names_the_key(small, tmp_path, run_cli):
    cfg, cloud = small
    bad = cfg.copy()
    bad.planner.standoff_m = 2.0
    with pytest.raises(ValueError, match="planner.standoff_m"):
        shotcrete.plan(cloud, bad)
    with pytest.raises(ValueError, match="arm=True"):
        shotcrete.plan(cloud, cfg, arm=False, robot=shotcrete.load_robot(cfg))
    yaml = tmp_path / "bad.yaml"
    yaml.write_text("planner: {mode: fastest}\n")
    r = run_cli("demo", "--out", tmp_path / "o", "--config", yaml)
    assert r.exit_code == 2 and "planner.mode" in r.output


def test_enum_fields_are_text_at_the_python_edge(small):
    cfg, _ = small
    c = cfg.copy()
    assert c.planner.mode == "optimal" and isinstance(c.planner.mode, str)
    c.planner.mode = "graded"
    c.planner.pass_direction = "circumferential"
    assert (c.planner.mode, c.planner.pass_direction) == ("graded", "circumferential")
    assert "mode: graded" in c.to_yaml() and "pass_direction: circumferential" in c.to_yaml()
    assert shotcrete.Config.from_yaml(c.to_yaml()).planner.mode == "graded"
    with pytest.raises(ValueError, match="planner.mode = 'fastest': expected one of graded, optimal"):
        c.planner.mode = "fastest"
    assert c.planner.mode == "graded"


def _check_cycle_time(report, traj, config):
    """Cycle time = the trajectory's duration, its parts add up to it, and the nozzle ratios agree
    with an independent finite-difference computation (numpy.gradient) on trajectory.npz."""
    t = traj["t_s"]
    assert report["cycle_time_s"] == report["total_time_s"] == pytest.approx(t[-1] - t[0], rel=1e-9)
    parts = report["cycle_time_breakdown_s"]
    assert set(parts) == {"spraying", "turn_arounds", "leads", "transits", "stop_and_go", "other"}
    assert sum(parts.values()) == pytest.approx(report["cycle_time_s"], rel=1e-12)
    assert parts["spraying"] == pytest.approx(report["trajectory"]["spray_time_s"], rel=1e-12)
    assert report["cycle_time_ratio"] == pytest.approx(report["cycle_time_s"] / report["physical_limit_s"], rel=1e-12)
    step = np.diff(t) > 1e-9  # numpy.gradient needs distinct times
    keep = np.concatenate([[True], step])
    p, tk = traj["nozzle_position_m"][keep], t[keep]
    v = np.gradient(p, tk, axis=0, edge_order=2)
    a = np.gradient(v, tk, axis=0, edge_order=2)
    speed = np.linalg.norm(v, axis=1).max() / config.timing.nozzle_max_speed_mps
    accel = np.linalg.norm(a, axis=1).max() / config.timing.nozzle_max_accel_mps2
    tr = report["trajectory"]
    assert tr["max_nozzle_speed_ratio"] == pytest.approx(speed, rel=0.05)
    assert tr["max_nozzle_accel_ratio"] == pytest.approx(accel, rel=0.25)  # a gradient of a gradient is coarser


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_graded_mode_leaves_no_cell_overfilled_on_the_default_bay(seed):
    # Issue 15: the thesis method on seeds 1-3 of the default bay leaves no cell at level -1
    # (the planner's deposit, which follows the timed path and the pump; the executed deposit
    # differs by well under a millimetre RMS, test_executed.py). The thesis's objective as
    # written left 123 / 14 / 51 cells below -50 mm here.
    cfg = shotcrete.load_config()
    cfg.synth.seed = seed
    cfg.planner.mode = "graded"
    surface = shotcrete.build_surface(shotcrete.synthetic_cloud(cfg), cfg)
    valid = np.asarray(surface.grid.valid).reshape(-1)
    plan = shotcrete.plan_bay(surface, cfg)
    r_mm = np.asarray(plan.td_after_m)[valid] * 1000.0
    assert r_mm.min() >= -50.0, f"seed {seed}: {int(np.sum(r_mm < -50))} cells below -50 mm, min {r_mm.min():.1f} mm"


def test_reversed_levelling_regions_lay_what_they_were_solved_for():
    """A levelling region's speeds are solved against its own timed deposit in the direction it was
    planned; the ordering may reverse it, but the pump's rules do not run the same both ways. Seed 6
    of the default bay (optimal mode): the second round's region, reversed, bridged a 1.7 s gap the
    solved direction kept off and laid 24 mm more on 970 points (3 cells at level -1). Every region
    the plan sprays reversed lays here, on the scanned wall, what it lays the other way to 3 mm."""
    cfg = shotcrete.load_config()
    cfg.synth.seed = 6
    surface = shotcrete.build_surface(shotcrete.synthetic_cloud(cfg), cfg)
    plan = shotcrete.plan_bay(surface, cfg)
    model = _core.spot_model_from_config(cfg.deposition)
    index = _core.SurfaceIndex(surface.cloud, 0.05)

    def deposit(passes):
        s = _core.region_spray(passes, cfg)
        poses = [_core.NozzlePose(p, a) for p, a in zip(np.asarray(s["positions_m"]), np.asarray(s["axes"]))]
        return _core.accumulate_dwells(model, index, poses, s["dwell_s"], cfg.deposition.rebound_fraction)

    def reversed_passes(passes):
        out = []
        for p in reversed(passes):
            q = _core.Pass()
            q.waypoints, q.speed_mps, q.length_m = list(reversed(p.waypoints)), p.speed_mps, p.length_m
            q.speed_profile_mps, q.line = list(reversed(p.speed_profile_mps)), p.line
            out.append(q)
        return out

    compared = 0
    for i, rnd in enumerate(plan.rounds):
        for j, region in enumerate(rnd.regions):
            if rnd.kind != "levelling" or not region.reversed:
                continue
            apart = np.abs(deposit(list(region.passes)) - deposit(reversed_passes(list(region.passes)))).max() * 1000
            assert apart < 3.0, f"round {i + 1}, region {j}: {apart:.1f} mm apart from its solved direction"
            compared += 1
    valid = np.asarray(surface.grid.valid).reshape(-1)
    assert (np.asarray(plan.td_after_m)[valid] * 1000).min() > -50.0
    assert compared >= 1  # the ordering still reverses where the pump lays the same both ways
