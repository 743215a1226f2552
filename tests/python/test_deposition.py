"""Deposition model through the bindings and the CLI: JSON output, bad CSVs, dtypes and shapes."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import shotcrete
from shotcrete import _core

ROOT = Path(__file__).resolve().parents[2]
CSV = ROOT / "data" / "deposition_stroke.csv"


def _json(output: str) -> dict:
    return json.loads(output[output.index("{"):])


def plane_cloud(n_side=41, h=0.01, z=1.0):
    g = (np.arange(n_side) - n_side // 2) * h
    x, y = np.meshgrid(g, g, indexing="ij")
    xyz = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
    normals = np.tile([0.0, 0.0, -1.0], (x.size, 1))
    return shotcrete.Cloud(xyz, normals)


def test_fit_cli_json_and_figure(run_cli, tmp_path):
    fig = tmp_path / "stroke.png"
    r = run_cli("deposition", "fit", CSV, "--standoff-mm", 1000, "--speed-mm-s", 150, "--json", "--figure", fig)
    assert r.exit_code == 0, r.output
    out = _json(r.output)
    assert out["mse_mm2"] < out["published_mse_mm2"] == 1.2
    assert 150 < out["radius_mm"] < 250 and 1.0 <= out["spot_beta"] < 4
    assert out["cone_half_angle_deg"] == pytest.approx(np.degrees(np.arctan(out["radius_mm"] / 1000.0)))
    assert out["flow_within_rebound"] is True
    assert out["deposited_flow_m3ph"] == pytest.approx(out["flow_m3ph"] * (1 - out["rebound_fraction"]))
    # The shipped config is the rounded fit of this file.
    cfg = shotcrete.load_config()
    assert cfg.deposition.spot_radius_m == out["config"]["spot_radius_m"]
    assert cfg.deposition.spot_beta == out["config"]["spot_beta"]
    assert cfg.deposition.peak_rate_mps == out["config"]["peak_rate_mps"]
    assert fig.is_file() and fig.stat().st_size > 10_000
    # Same numbers as the bindings, and the speed scales q_max linearly.
    fit = _core.fit_stroke(_core.read_stroke_csv(str(CSV)))
    assert out["mse_mm2"] == pytest.approx(fit.mse_mm2, rel=1e-12)
    r2 = run_cli("deposition", "fit", CSV, "--speed-mm-s", 300, "--json")
    assert _json(r2.output)["q_max_mm_s"] == pytest.approx(2 * out["q_max_mm_s"], rel=1e-6)


@pytest.mark.parametrize("text, message", [
    ("position_mm,thickness_mm\n0,1\n10,2\n20,1\n", "at least 5"),
    ("position_mm,thickness_mm\n0,1\n10,two\n20,1\n30,1\n40,1\n", "non-numeric thickness 'two'"),
    ("position_mm,thickness_mm\n0,1\n10,-2\n20,1\n30,1\n40,1\n", "negative thickness"),
    ("position_mm,thickness_mm\n0,0\n10,0\n20,0\n30,0\n40,0\n", "all thickness values are zero"),
])
def test_fit_cli_bad_csv_exit_2(run_cli, tmp_path, text, message):
    bad = tmp_path / "bad.csv"
    bad.write_text(text)
    r = run_cli("deposition", "fit", bad)
    assert r.exit_code == 2, r.output
    assert message in r.output and "Traceback" not in r.output
    with pytest.raises(ValueError, match=message):
        _core.read_stroke_csv(str(bad))


def test_fit_cli_huge_thickness_is_refused_not_a_segfault(tmp_path):
    """Issue 17: one thickness of 1e300 crashed `deposition fit` (segfault in fit_stroke). In a child
    process, so a crash shows as a signal instead of killing pytest."""
    bad = tmp_path / "huge.csv"
    bad.write_text(CSV.read_text().replace("\n-140,10\n", "\n-140,1e300\n"))
    assert "1e300" in bad.read_text()
    r = subprocess.run([str(Path(sys.executable).parent / "shotcrete"), "deposition", "fit", str(bad)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert "thickness 1e300 mm is above the physical limit of 1000 mm" in r.stderr
    assert "Traceback" not in r.stderr
    data = _core.read_stroke_csv(str(CSV))
    th = np.array(data.thickness_m)
    th[3] = 1e297  # 1e300 mm
    data = _core.StrokeData(np.array(data.position_m), th)
    with pytest.raises(ValueError, match="sample 3 .* outside the physical range"):
        _core.fit_stroke(data)


def test_fit_cli_missing_file_and_bad_speed(run_cli, tmp_path):
    r = run_cli("deposition", "fit", tmp_path / "nope.csv")
    assert r.exit_code == 2 and "cannot open" in r.output
    r = run_cli("deposition", "fit", CSV, "--speed-mm-s", 0)
    assert r.exit_code == 2 and "speed" in r.output


def test_spacing_cli_json_scale_free(run_cli, tmp_path):
    r = run_cli("deposition", "spacing", "--target-mm", 50, "--json")
    assert r.exit_code == 0, r.output
    a = _json(r.output)
    assert a["spacing_mm"] + a["overlap_mm"] == pytest.approx(2 * a["radius_mm"])
    assert a["band_min_mm"] < 50 < a["band_max_mm"] * 1.1
    b = _json(run_cli("deposition", "spacing", "--target-mm", 100, "--json").output)
    assert b["spacing_mm"] == pytest.approx(a["spacing_mm"], abs=1e-3)
    assert b["band_min_mm"] == pytest.approx(2 * a["band_min_mm"], rel=1e-6)
    # A config with a wider spot gives a wider spacing.
    cfg = tmp_path / "wide.yaml"
    cfg.write_text("deposition:\n  spot_radius_m: 0.3\n")
    c = _json(run_cli("deposition", "spacing", "--target-mm", 50, "--json", "--config", cfg).output)
    assert c["spacing_mm"] == pytest.approx(a["spacing_mm"] * 0.3 / (a["radius_mm"] / 1000), rel=2e-3)
    r = run_cli("deposition", "spacing", "--target-mm", -1)
    assert r.exit_code == 2 and "target" in r.output


def test_bindings_dtypes_shapes_and_in_place_update():
    cfg = shotcrete.load_config()
    model = _core.spot_model_from_config(cfg.deposition)
    cloud = plane_cloud()
    index = _core.SurfaceIndex(cloud)
    assert len(index) == len(cloud) and index.cell_size_m == pytest.approx(0.05)
    poses = _core.nozzle_poses(np.array([[-0.3, 0, 0], [0.3, 0, 0]]), np.array([[0, 0, 1.0]]))
    t = _core.accumulate_pass(model, index, poses, 0.15, 0.01, 0.08)
    assert isinstance(t, np.ndarray) and t.dtype == np.float64 and t.shape == (len(cloud),)
    # The cross line at x = 0 reproduces the closed-form stroke minus rebound.
    centre = np.abs(cloud.xyz[:, 0]) < 1e-9
    expected = _core.stroke_thickness_m(model, cloud.xyz[centre, 1], 0.15) * 0.92
    np.testing.assert_allclose(t[centre], expected, rtol=0, atol=1e-4)  # 10 mm steps: 0.1 mm
    # In place: the same array object is updated and returned.
    same = _core.accumulate_pass(model, index, poses, 0.15, 0.01, 0.08, t)
    assert same is t
    np.testing.assert_allclose(t[centre], 2 * expected, rtol=0, atol=2e-4)
    with pytest.raises(ValueError, match="shape"):
        _core.accumulate_pass(model, index, poses, 0.15, 0.01, 0.08, np.zeros(3))
    with pytest.raises(TypeError):
        _core.accumulate_pass(model, index, poses, 0.15, 0.01, 0.08, np.zeros(len(cloud), dtype=np.float32))
    # Dwells agree with the resampled pass.
    samples = _core.resample_pass(poses, 0.15, 0.01)
    assert samples.dwell_s.dtype == np.float64 and samples.dwell_s.shape == (60,)
    d = _core.accumulate_dwells(model, index, samples.poses, list(samples.dwell_s), 0.08)
    np.testing.assert_array_equal(d, _core.accumulate_pass(model, index, poses, 0.15, 0.01, 0.08))
    # Spatial query, moved cloud, point rate.
    idx = index.within(np.array([0.0, 0.0, 1.0]), 0.05)
    assert idx.dtype == np.int32 and np.all(np.diff(idx) > 0)
    brute = np.flatnonzero(np.linalg.norm(cloud.xyz - [0, 0, 1.0], axis=1) <= 0.05)
    np.testing.assert_array_equal(idx, brute)
    q = _core.point_rate_mps(model, _core.NozzlePose([0, 0, 0], [0, 0, 1]), [0.05, 0, 1.0], [0, 0, -1])
    assert q == pytest.approx(float(model.rate_at(0.05)))
    default = _core.SpotModel()
    assert (default.radius_m, default.beta, default.peak_rate_mps) == (model.radius_m, model.beta, model.peak_rate_mps)
    r = model.rate_at(np.linspace(0, 0.3, 7))
    assert r.shape == (7,) and r[-1] == 0.0


def test_sprayed_wall_takes_the_planners_deposit(small_config, small_cloud):
    surface = shotcrete.build_surface(small_cloud, small_config)
    wall = _core.unsprayed_wall(surface, small_config.profile.max_deviation_m)
    cells = wall.cell_of_point
    assert cells.dtype == np.int32 and cells.shape == (len(surface.cloud),)
    valid = np.asarray(surface.grid.valid).reshape(-1)
    before = np.asarray(wall.surface.grid.td_m).reshape(-1).copy()
    xyz0 = np.asarray(wall.surface.cloud.xyz).copy()
    t = np.full(len(surface.cloud), 0.02)
    _core.deposit_layer(wall, t)  # in place
    drop = (before - np.asarray(wall.surface.grid.td_m).reshape(-1))[valid]
    # Along the rays: at least the layer, at most twice it (tilt capped at 60 degrees).
    assert drop.min() >= 0.02 - 1e-9 and drop.max() <= 0.04 + 1e-9
    moved = np.asarray(wall.surface.cloud.xyz)
    np.testing.assert_array_equal(moved[:, 0], xyz0[:, 0])  # d stays: every point keeps its cell
    r0, r1 = np.hypot(xyz0[:, 1], xyz0[:, 2]), np.hypot(moved[:, 1], moved[:, 2])
    assert np.all(r0 - r1 >= 0.02 - 1e-9)
    np.testing.assert_array_equal(wall.cell_of_point, cells)
    assert list(wall.surface.levels) == list(_core.cell_levels(wall.surface.grid))  # re-graded
    with pytest.raises(ValueError, match="thicknesses"):
        _core.deposit_layer(wall, np.zeros(3))


def test_stroke_data_and_fit_objects():
    data = _core.read_stroke_csv(str(CSV), 1.0, 0.15, 0.08)
    assert len(data) == 21 and data.position_m.dtype == np.float64 and data.thickness_m.shape == (21,)
    fit = _core.fit_stroke(data)
    prof = fit.stroke_at_m(data.position_m)
    assert prof.shape == (21,)
    assert np.mean((prof - data.thickness_m) ** 2) * 1e6 == pytest.approx(fit.mse_mm2, rel=1e-9)
    own = _core.fit_stroke(_core.StrokeData(list(data.position_m), list(data.thickness_m), 1.0, 0.15, 0.08))
    assert own.model.radius_m == pytest.approx(fit.model.radius_m, rel=1e-12)
    with pytest.raises(ValueError, match="at least 5"):
        _core.fit_stroke(_core.StrokeData([0, 1], [1, 1]))


def test_spot_model_from_config_rejects_zero_rate():
    cfg = shotcrete.load_config()
    with pytest.raises(ValueError):
        cfg.deposition.peak_rate_mps = 0.0
        _core.spot_model_from_config(cfg.deposition)
