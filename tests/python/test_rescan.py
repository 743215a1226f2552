"""The closed loop after spraying (issue 19): demo job -> before-scan with its surroundings ->
synthetic after-scan (1 deg / 0.1 m off, flow x 0.85) -> shotcrete rescan. Every figure of the
report is checked against the ground truth written beside the after-scan, recomputed with numpy
from the files; bad input gives one error line, exit 2, and leaves OUT untouched."""
import csv
import json
import re

import numpy as np
import pytest

import shotcrete
from shotcrete import _core


def _one_error_line(output: str) -> str:
    lines = [ln for ln in output.splitlines() if ln.strip() and not re.fullmatch(r"[a-z0-9 ]+ [━ ]* ?\d+:\d\d:\d\d", ln)]
    assert len(lines) == 1 and lines[0].startswith("error: "), output
    assert "Traceback" not in output
    return lines[0]


def _csv(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) if r[k] != "" else np.nan for r in rows]) for k in rows[0]}


@pytest.fixture(scope="module")
def loop(tmp_path_factory, run_cli_module):
    d = tmp_path_factory.mktemp("loop")
    cfg = shotcrete.load_config()
    cfg.synth.theta_min_rad, cfg.synth.theta_max_rad, cfg.synth.length_m = 1.0, 2.0, 0.6
    cfg.synth.context_enabled = True
    cfg.synth.context_previous_bay_m = 1.0
    cfg.clearance.enabled = False
    (d / "cfg.yaml").write_text(cfg.to_yaml())
    cfg.synth.after_flow_scale = 0.85
    cfg.synth.after_pose_rpy_rad = [0.003, -0.008, 0.012]  # 0.84 deg
    cfg.synth.after_pose_translation_m = [0.06, -0.05, 0.06]  # 0.10 m
    (d / "cfg_after.yaml").write_text(cfg.to_yaml())
    run = run_cli_module
    assert run("demo", "--config", d / "cfg.yaml", "--out", d / "job").exit_code in (0, 3)
    assert run("synth", "--config", d / "cfg.yaml", "--out", d / "before.ply").exit_code == 0
    r = run("synth", "--config", d / "cfg_after.yaml", "--after", d / "job", "--out", d / "after.ply")
    assert r.exit_code == 0, r.output
    r = run("rescan", d / "before.ply", d / "after.ply", "--job", d / "job", "--config", d / "cfg.yaml",
            "--out", d / "out", "--write-config", d / "calibrated.yaml", "--per-point", 3000)
    assert r.exit_code == 0, r.output
    return d


@pytest.fixture(scope="module")
def run_cli_module():
    from typer.testing import CliRunner

    from shotcrete.cli import app

    runner = CliRunner()
    return lambda *args: runner.invoke(app, [str(a) for a in args], catch_exceptions=False)


def test_registration_recovers_the_true_pose(loop):
    rep = json.loads((loop / "out" / "report.json").read_text())
    truth = json.loads((loop / "after_truth.json").read_text())
    T, Tt = np.array(rep["registration"]["matrix"]), np.array(truth["pose_after_to_before"])
    E = np.linalg.inv(T) @ Tt
    v = np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
    assert np.degrees(np.arctan2(np.linalg.norm(v) / 2, (np.trace(E[:3, :3]) - 1) / 2)) < 0.05
    assert rep["registration"]["rotation_deg"] == pytest.approx(np.degrees(np.arccos((np.trace(T[:3, :3]) - 1) / 2)), abs=1e-4)
    # A 1 rad slice of the crown gives little grip across the tunnel (y): 3.4 mm there, against
    # 0.05-0.24 mm on the whole bay (bench_rescan); the 3 mm target is the bench's.
    assert np.linalg.norm(E[:3, 3]) < 0.005
    assert rep["registration"]["overlap"] > 0.9


def test_thickness_per_cell_against_truth_and_report_figures_from_cells_csv(loop):
    rep = json.loads((loop / "out" / "report.json").read_text())
    cells, truth = _csv(loop / "out" / "cells.csv"), _csv(loop / "after_truth.csv")
    assert np.array_equal(cells["cell"], truth["cell"])
    m, t, p = cells["measured_mm"], truth["true_thickness_mm"], cells["predicted_mm"]
    ok = np.isfinite(m)
    assert ok.mean() > 0.99
    err = m[ok] - t[ok]
    # The slice's registration error across the tunnel (above) adds up to ~2 mm by theta: 3.1 mm RMS
    # here, 2.1 mm on the whole bay (bench_rescan).
    assert abs(err.mean()) < 1.0 and np.sqrt(np.mean(err ** 2)) < 4.0
    # The report's measured vs predicted, from cells.csv (rounded to 0.01 mm).
    diff = m[ok] - p[ok]
    mvp = rep["measured_vs_predicted_mm"]
    assert mvp["cells"] == ok.sum()
    assert mvp["bias"] == pytest.approx(diff.mean(), abs=0.01)
    assert mvp["rms"] == pytest.approx(np.sqrt(np.mean(diff ** 2)), abs=0.01)
    assert rep["thickness_mm"]["mean"] == pytest.approx(m[ok].mean(), abs=0.01)
    # Residual = TD before - measured, per cell.
    assert np.allclose(cells["residual_td_mm"][ok], cells["td_before_mm"][ok] - m[ok], atol=0.02)
    # The uncertainty covers the error about as often as a 95 % level should (noise is not all of it:
    # the layer's own roughness inside a cell is in the truth).
    assert np.mean(np.abs(err) <= cells["lod95_mm"][ok]) > 0.85


def test_calibrated_factor_against_the_truth_and_numpy(loop):
    rep = json.loads((loop / "out" / "report.json").read_text())
    cells, truth = _csv(loop / "out" / "cells.csv"), _csv(loop / "after_truth.csv")
    cal = rep["calibration"]
    m, p, t = cells["measured_mm"], cells["predicted_mm"], truth["true_thickness_mm"]
    use = np.isfinite(m) & (p >= 20.0)
    # The factor the truth itself realises (its correlated noise moves it off 0.85 on a small bay).
    realised = np.sum(t[use] * p[use]) / np.sum(p[use] ** 2)
    assert cal["flow_factor"] == pytest.approx(realised, rel=0.005)
    assert cal["flow_factor"] == pytest.approx(0.85, rel=0.03)
    # The robust fit: least squares, refitted without cells beyond 3 x 1.4826 MAD, from cells.csv
    # (measured and predicted rounded to 0.01 mm there).
    keep = use.copy()
    for _ in range(6):
        f = np.sum(m[keep] * p[keep]) / np.sum(p[keep] ** 2)
        res = m - f * p
        a = np.sort(np.abs(res[keep]))
        lim = 3 * 1.4826 * a[len(a) // 2]  # the core's median: the upper one of an even count
        new = keep & (np.abs(res) <= lim)
        if new.sum() == keep.sum():
            break
        keep = new
    # cells.csv rounds to 0.01 mm: a cell's residual moves by about that, the limit (3 x 1.4826 x
    # the median) by up to 0.045 mm, and the factor the residuals are taken at, by the cells that
    # fall the other way, by about 1e-4, 0.025 mm on a 250 mm prediction: a cell within 0.1 mm of the
    # limit may fall either way in the core (seen: three at 0.014, 0.020 and 0.085 mm inside it), so
    # the core's factor is one of the fits with any of them left out.
    near = np.flatnonzero(use & (np.abs(np.abs(res) - lim) < 0.1))
    assert len(near) <= 6
    fits = []
    for leave_out in range(1 << len(near)):
        k = keep.copy()
        k[near] = [(leave_out >> i) & 1 == 0 for i in range(len(near))]
        fits.append(np.sum(m[k] * p[k]) / np.sum(p[k] ** 2))
    assert min(fits) * (1 - 2e-5) <= cal["flow_factor"] <= max(fits) * (1 + 2e-5), (cal["flow_factor"], min(fits), max(fits))
    assert abs(cal["cells"] - keep.sum()) <= len(near)  # rounding may move the cells at the limit
    # --write-config: the copy holds the calibrated rate; the job's config is untouched.
    written = shotcrete.load_config(loop / "calibrated.yaml")
    base = shotcrete.load_config(loop / "cfg.yaml")
    assert written.deposition.peak_rate_mps == pytest.approx(base.deposition.peak_rate_mps * cal["flow_factor"])
    assert base.deposition.peak_rate_mps == shotcrete.load_config().deposition.peak_rate_mps


def test_corrective_round_planned_on_the_measured_residual(loop):
    rep = json.loads((loop / "out" / "report.json").read_text())
    corr = rep["correction"]
    cells = _csv(loop / "out" / "cells.csv")
    ok = np.isfinite(cells["residual_td_mm"])
    # The corrective round's TD before is the after-scan's wall: the measured residual, cell by cell on average.
    assert corr["td_before_mm"]["mean"] == pytest.approx(np.mean(cells["residual_td_mm"][ok]), abs=2.0)
    assert corr["deposition_peak_rate_mps"] == pytest.approx(
        shotcrete.load_config().deposition.peak_rate_mps * rep["calibration"]["flow_factor"])
    assert corr["rounds"] >= 1 and corr["levels_after"] == {"0": corr["levels_after"]["0"]}
    # Planned with the finishing layer's time weight, not the job's.
    cfg = shotcrete.load_config(loop / "cfg.yaml")
    assert corr["time_weight_mm2_per_s"] == cfg.rescan.correction_time_weight_mm2_per_s != cfg.planner.time_weight_mm2_per_s
    # ... on lines at the two-pass spacing, not the job's close ones.
    assert corr["levelling_spacing_ratio"] == cfg.rescan.correction_spacing_ratio != cfg.planner.levelling_spacing_ratio
    assert corr["edge_overrun_m"] == cfg.rescan.correction_edge_overrun_m != cfg.planner.edge_overrun_m
    assert (loop / "out" / "plan.json").is_file()
    html = (loop / "out" / "report.html").read_text()
    for f in rep["files"]["figures"]:
        assert f in html and (loop / "out" / f).is_file()


def test_per_point_layer_against_the_truth_of_its_cell(loop):
    rep = json.loads((loop / "out" / "report.json").read_text())
    assert rep["per_point"]["points"] == 3000 and rep["files"]["points"] == "points.ply"
    pts = shotcrete.read_cloud(loop / "out" / "points.ply")
    xyz = np.asarray(pts.xyz)
    assert len(xyz) == 3000
    # Each point's layer (in the PLY's intensity, re-measured here through the API) against the truth
    # of the cell it lies in: the cell's mean, so the layer's variation inside a cell adds a little.
    cfg = shotcrete.load_config(loop / "cfg.yaml")
    from shotcrete import rescan as rs

    job = rs.read_job(loop / "job", cfg)
    truth = _csv(loop / "after_truth.csv")
    by_cell = dict(zip(truth["cell"].astype(int), truth["true_thickness_mm"]))
    T = np.array(rep["registration"]["matrix"])
    after = shotcrete.read_cloud(loop / "after.ply")
    after_reg = _core.transform_cloud(after, T)
    r = _core.measure_points(job.grid.axis, _core.Cloud(xyz).xyz, shotcrete.read_cloud(loop / "before.ply"), after_reg,
                             cfg.rescan)
    m = np.asarray(r.distance_m) * 1000
    cells = [job.grid.cell_at(*job.grid.axis.to_cylindrical(p)[1:]) for p in xyz]
    t = np.array([by_cell.get(c, np.nan) for c in cells])
    ok = np.isfinite(m) & np.isfinite(t)
    assert ok.mean() > 0.95
    # Per point: ~16 points per cylinder and scan, and the layer's variation inside the cell.
    assert abs(np.mean(m[ok] - t[ok])) < 1.5 and np.sqrt(np.mean((m[ok] - t[ok]) ** 2)) < 8.0
    assert rep["per_point"]["thickness_mm"]["mean"] == pytest.approx(np.nanmean(m), abs=0.5)


def _shifted(src, dst, dx):
    c = shotcrete.read_cloud(src)
    xyz = np.asarray(c.xyz).copy()
    xyz[:, 0] += dx
    shotcrete.write_cloud(dst, _core.Cloud(xyz))
    return dst


def test_bad_inputs_one_line_exit_2_and_out_untouched(loop, run_cli_module, tmp_path):
    run = run_cli_module
    out = tmp_path / "out"
    base = [loop / "before.ply", loop / "after.ply", "--job", loop / "job", "--config", loop / "cfg.yaml", "--out", out]
    (tmp_path / "empty.xyz").write_text("")
    (tmp_path / "nan.xyz").write_text("1 2 3\nnan 0 0\n4 5 6\n")
    cases = [
        ([loop / "before.ply", loop / "after.ply", "--job", tmp_path / "nojob", "--out", out, "--config", loop / "cfg.yaml"],
         "no such job directory"),
        ([loop / "before.ply", tmp_path / "empty.xyz"] + base[2:], "empty.xyz"),
        ([tmp_path / "nan.xyz", loop / "after.ply"] + base[2:], "nan.xyz"),
        ([loop / "before.ply", _shifted(loop / "after.ply", tmp_path / "far.ply", 50.0)] + base[2:],
         "another bay"),
        (base + ["--reference", "mask"], "--reference mask needs --mask"),
        (base + ["--units", "mm"], "no reference area"),
        (base + ["--write-config", loop / "cfg.yaml"], "exists; pass --force"),
    ]
    for args, needle in cases:
        r = run("rescan", *args)
        assert r.exit_code == 2, (args, r.output)
        assert needle in _one_error_line(r.output), r.output
        assert not out.exists()
    # A job planned with another design radius (the wrong config): refused by name.
    other = shotcrete.load_config(loop / "cfg.yaml")
    other.profile.design_radius_m = 6.0
    (tmp_path / "other.yaml").write_text(other.to_yaml())
    r = run("rescan", *base[:5], tmp_path / "other.yaml", "--out", out)
    assert r.exit_code == 2 and "profile.design_radius_m" in _one_error_line(r.output)
    # synth --after on a job of another bay (another seed).
    r = run("synth", "--config", loop / "cfg_after.yaml", "--seed", "7", "--after", loop / "job", "--out", tmp_path / "a.ply")
    assert r.exit_code == 2 and "not planned on this synthetic bay" in _one_error_line(r.output)
    assert not (tmp_path / "a.ply").exists()


def test_python_api_matches_the_cli(loop):
    cfg = shotcrete.load_config(loop / "cfg.yaml")
    from shotcrete import rescan as rs

    job = rs.read_job(loop / "job", cfg)
    res = rs.rescan(shotcrete.read_cloud(loop / "before.ply"), shotcrete.read_cloud(loop / "after.ply"), job, cfg,
                    correct=False)
    rep = json.loads((loop / "out" / "report.json").read_text())
    assert res.summary["calibration"]["flow_factor"] == pytest.approx(rep["calibration"]["flow_factor"], rel=1e-9)
    assert "correction" not in res.summary
    for fn in (rs.read_job, rs.after_scan, rs.rescan, rs.write_outputs, _core.register_scans, _core.measure_cells,
               _core.calibrate_flow, _core.m3c2):
        assert fn.__doc__ and len(fn.__doc__) > 40


def test_the_correction_is_sprayed_from_where_the_job_placed_the_base(loop):
    """rescan's robot (``job_robot``): the job's base as its report.json ``base_placement`` gives it
    when the job moved it (robot.place_base), else the configured one; the loop's job (clearance
    off) was not placed."""
    import dataclasses

    from shotcrete import rescan as rs

    cfg = shotcrete.load_config(loop / "cfg.yaml")
    job = rs.read_job(loop / "job", cfg)
    robot = shotcrete.load_robot(cfg)
    assert "base_placement" not in job.report
    base = lambda r: np.asarray(r.base_pose)[:3, 3]  # noqa: E731
    assert np.allclose(base(rs.job_robot(job, robot)), cfg.robot.base_position_m)
    placed = dataclasses.replace(job, report={**job.report, "base_placement": {"moved": True, "position_m": [0.1, 0.0, -1.2]}})
    assert np.allclose(base(rs.job_robot(placed, robot)), [0.1, 0.0, -1.2])
    kept = dataclasses.replace(job, report={**job.report, "base_placement": {"moved": False, "position_m": [0.6, 0.0, -1.2]}})
    assert np.allclose(base(rs.job_robot(kept, robot)), cfg.robot.base_position_m)
    # The arm moved: its forward kinematics with it.
    q = np.asarray(robot.stow())
    shift = np.asarray(robot.fk(q))[:3, 3] - np.asarray(rs.job_robot(placed, robot).fk(q))[:3, 3]
    assert np.allclose(shift, np.asarray(cfg.robot.base_position_m) - [0.1, 0.0, -1.2])
