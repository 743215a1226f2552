"""Surface stage through the bindings, the file formats and the CLI."""
import json

import numpy as np
import pytest

import shotcrete
from conftest import cylinder_points


def test_cloud_round_trip_through_bindings():
    xyz = cylinder_points(500)
    cloud = shotcrete.Cloud(xyz)
    assert cloud.xyz.dtype == np.float64 and cloud.xyz.shape == (500, 3)
    np.testing.assert_array_equal(cloud.xyz, xyz)
    assert cloud.normals.shape == (0, 3) and not cloud.has_normals()
    with pytest.raises(ValueError, match="one row per point"):
        shotcrete.Cloud(xyz, np.zeros((3, 3)))
    # float32 and Fortran-ordered input are converted, not misread.
    cloud32 = shotcrete.Cloud(np.asfortranarray(xyz.astype(np.float32)))
    np.testing.assert_allclose(cloud32.xyz, xyz, rtol=1e-6)


def test_surface_arrays_have_documented_shapes(small_config, small_cloud):
    s = shotcrete.build_surface(small_cloud, small_config)
    g = s.grid
    assert g.td_m.shape == (g.n_theta, g.n_d) and g.td_m.dtype == np.float64
    assert g.valid.dtype == bool and g.count.shape == (g.n_theta, g.n_d)
    assert g.mean_xyz.shape == (g.n_theta * g.n_d, 3)
    assert len(s.levels) == g.n_theta * g.n_d
    assert s.cloud.has_normals()
    # Normals point toward the axis: dot with the radial direction is negative.
    radial = s.cloud.xyz * np.array([0, 1, 1])
    assert np.all(np.einsum("ij,ij->i", s.cloud.normals, radial) < 0)
    assert set(s.timings_s) >= {"preprocess", "normals", "grid"}


def test_td_matches_the_generator(small_config, small_cloud):
    bay = shotcrete.make_synthetic_bay(small_config.synth)
    s = shotcrete.build_surface(small_cloud, small_config)
    g = s.grid
    err = []
    for row in range(1, g.n_theta - 1):  # edge cells are only partly covered by the slice
        for col in range(1, g.n_d - 1):
            if g.count[row, col] >= 6:
                err.append(g.td_m[row, col] - bay.td_at(g.d_center(col), g.theta_center(row)))
    assert len(err) > 100
    # 5 mm scanner noise over 6-8 points per cell: about 2 mm RMS.
    assert np.sqrt(np.mean(np.square(err))) < 0.004
    assert np.max(np.abs(err)) < 0.015


@pytest.mark.parametrize("ext", [".pcd", ".ply", ".xyz", ".las", ".laz"])
def test_io_round_trip(tmp_path, ext):
    cloud = shotcrete.Cloud(cylinder_points(300))
    path = shotcrete.write_cloud(tmp_path / f"c{ext}", cloud)
    back = shotcrete.read_cloud(path)
    assert len(back) == 300
    np.testing.assert_allclose(back.xyz, cloud.xyz, atol=2e-4)  # float32 / LAS 0.1 mm scale


def test_e57_read(tmp_path):
    pye57 = pytest.importorskip("pye57")
    xyz = cylinder_points(200)
    path = tmp_path / "scan.e57"
    e57 = pye57.E57(str(path), mode="w")
    e57.write_scan_raw({"cartesianX": xyz[:, 0], "cartesianY": xyz[:, 1], "cartesianZ": xyz[:, 2]})
    e57.close()
    back = shotcrete.read_cloud(path)
    np.testing.assert_allclose(back.xyz, xyz, atol=1e-9)


def test_bad_files_raise_value_error(tmp_path):
    junk = tmp_path / "junk.ply"
    junk.write_text("hello\n")
    with pytest.raises(ValueError, match="not a PLY"):
        shotcrete.read_cloud(junk)
    with pytest.raises(ValueError, match="no such file"):
        shotcrete.read_cloud(tmp_path / "missing.pcd")
    las = tmp_path / "junk.las"
    las.write_bytes(b"\x00" * 64)
    with pytest.raises(ValueError, match="LAS"):
        shotcrete.read_cloud(las)
    with pytest.raises(ValueError, match="unknown cloud format"):
        (tmp_path / "c.obj").write_text("v 1 2 3\n")
        shotcrete.read_cloud(tmp_path / "c.obj")


def test_bad_clouds_raise_value_error(small_config):
    with pytest.raises(ValueError, match="empty"):
        shotcrete.build_surface(shotcrete.Cloud(np.zeros((0, 3))), small_config)
    xyz = cylinder_points(500)
    xyz[10, 2] = np.inf
    with pytest.raises(ValueError, match="non-finite"):
        shotcrete.build_surface(shotcrete.Cloud(xyz), small_config)
    with pytest.raises(ValueError, match="millimetres"):
        shotcrete.build_surface(shotcrete.Cloud(cylinder_points(500) * 1000), small_config)
    far = shotcrete.load_config()
    far.profile.design_radius_m = 9.0
    with pytest.raises(ValueError, match="design radius"):
        shotcrete.build_surface(shotcrete.Cloud(cylinder_points(500)), far)


def test_config_errors_name_the_key(tmp_path):
    cfg = shotcrete.load_config()
    cfg.profile.design_radius_m = -1
    with pytest.raises(ValueError, match="profile.design_radius_m"):
        cfg.validate()
    bad = tmp_path / "bad.yaml"
    bad.write_text("grid:\n  cell_size_mm: 50\n")
    with pytest.raises(ValueError, match="unknown key 'grid.cell_size_mm'"):
        shotcrete.load_config(bad)
    assert shotcrete.Config.from_yaml(cfg.copy().to_yaml().replace("-1", "6")).profile.design_radius_m == 6
    assert "design_radius_m" in shotcrete.ProfileConfig.KEYS


def test_cli_synth_then_plan(tmp_path, run_cli):
    cloud = tmp_path / "bay.pcd"
    r = run_cli("synth", "--out", cloud, "--seed", 4)
    assert r.exit_code == 0, r.output
    r = run_cli("synth", "--out", cloud)
    assert r.exit_code == 2 and "exists" in r.output
    out = tmp_path / "job"
    r = run_cli("plan", cloud, "--out", out, "--json")
    assert r.exit_code == 0, r.output
    report = json.loads((out / "report.json").read_text())
    assert report["cells"] > 8000
    assert min(int(k) for k in report["levels_before"]) >= 2
    assert {"surface_preprocess", "surface_normals", "surface_grid", "plan_simulate_and_time"} <= set(report["timings_s"])
    assert report["levels_after"] and report["rounds"] >= 1 and report["passes"] > 0
    assert (out / "plan.json").is_file() and (out / "sprayed.ply").is_file()
    assert (out / "report.html").is_file() and (out / "figures" / "td_before.png").is_file()
    # A second run into the same directory is allowed (ours); a foreign non-empty one is not.
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    r = run_cli("plan", cloud, "--out", foreign)
    assert r.exit_code == 2 and "not empty" in r.output
    assert (foreign / "notes.txt").read_text() == "keep me"


def test_cli_bad_inputs_exit_2(tmp_path, run_cli):
    junk = tmp_path / "junk.pcd"
    junk.write_text("not a cloud")
    r = run_cli("plan", junk, "--out", tmp_path / "o1")
    assert r.exit_code == 2 and "not a PCD" in r.output
    empty = tmp_path / "empty.xyz"
    empty.write_text("")
    r = run_cli("plan", empty, "--out", tmp_path / "o2")
    assert r.exit_code == 2 and "empty" in r.output
    mm = tmp_path / "mm.xyz"
    np.savetxt(mm, cylinder_points(800) * 1000)
    r = run_cli("plan", mm, "--out", tmp_path / "o3")
    assert r.exit_code == 2 and "millimetres" in r.output
    cfg = tmp_path / "neg.yaml"
    cfg.write_text("profile:\n  design_radius_m: 0\n")
    r = run_cli("plan", mm, "--out", tmp_path / "o4", "--config", cfg)
    assert r.exit_code == 2 and "design_radius_m" in r.output


def test_cli_plan_of_a_scene_grids_the_bay_and_keeps_the_rest(tmp_path, run_cli, small_config, small_cloud):
    """Issue 16: a scan holding the bay, 0.5 m of lining behind it and the face: the detected bay
    gets the same cells and required volume as the bay scanned alone, report.json says where it
    lies, and the lining and face stay in the written clouds (obstacles, references), unmoved."""
    rng = np.random.default_rng(3)
    R = small_config.profile.design_radius_m
    n = 20000
    d, th = -0.5 * rng.random(n), 1.0 + rng.random(n)
    r = R + rng.normal(0.0, 0.005, n)
    lining = np.c_[d, r * np.cos(th), r * np.sin(th)]
    rr, th = (R + 0.15) * np.sqrt(rng.random(n)), 1.0 + rng.random(n)
    face = np.c_[0.65 + rng.normal(0.0, 0.005, n), rr * np.cos(th), rr * np.sin(th)]
    bay = np.asarray(small_cloud.xyz)
    files = {}
    for name, xyz in (("bay", bay), ("scene", np.vstack([bay, lining, face]))):
        files[name] = tmp_path / f"{name}.ply"
        shotcrete.write_cloud(files[name], shotcrete.Cloud(xyz))
    cfg = tmp_path / "small.yaml"
    cfg.write_text("synth:\n  theta_min_rad: 1.0\n  theta_max_rad: 2.0\n  length_m: 0.6\n"
                   "planner:\n  max_rounds: 2\nclearance:\n  enabled: false\n")
    reports = {}
    for name, path in files.items():
        r = run_cli("plan", path, "--out", tmp_path / name, "--config", cfg, "--json")
        assert r.exit_code in (0, 3), r.output
        reports[name] = json.loads((tmp_path / name / "report.json").read_text())
    alone, scene = reports["bay"], reports["scene"]
    assert alone["bay"]["lined_columns"] == 0 and alone["bay"]["points_outside_bay"] == 0
    assert scene["bay"]["selection"] == "detect"
    assert scene["bay"]["start_m"] == pytest.approx(0.0, abs=1e-9) and scene["bay"]["end_m"] == pytest.approx(0.6, abs=1e-9)
    assert scene["bay"]["scan_start_m"] == pytest.approx(-0.5, abs=0.051) and scene["bay"]["lined_columns"] >= 9
    assert scene["bay"]["points_outside_bay"] > 15000 and scene["bay"]["points_not_wall"] > 1000
    # The same grid; a few cells empty in the sparse bay alone get a face-rim point in the scene.
    assert scene["grid_shape"] == alone["grid_shape"] and 0 <= scene["cells"] - alone["cells"] <= 5
    assert scene["required_volume_m3"] == pytest.approx(alone["required_volume_m3"], rel=0.003)
    page = (tmp_path / "scene" / "report.html").read_text()
    assert "chainage 0.00..0.60 m of the scan" in page and "detected: the stretch that is not lining" in page
    # The lining stays in the sprayed cloud: beyond the passes' overrun (0.1 m) and the spot
    # (0.19 m) where the plan left it; nearer the bay it got the overspray, as it would.
    sprayed = np.asarray(shotcrete.read_cloud(tmp_path / "scene" / "sprayed.ply").xyz)
    assert len(sprayed) > len(bay) + n  # the preprocessed scene (voxel filter), lining and face included
    behind = sprayed[sprayed[:, 0] < -0.4]
    assert len(behind) > 3000
    assert np.abs(np.hypot(behind[:, 1], behind[:, 2]) - R).max() < 0.05
