"""Design sections (issue 16): the DXF converter, the CLI check, and a plan on a horseshoe."""
import csv
import json
import math

import numpy as np
import pytest

import shotcrete
from shotcrete import _core

HORSESHOE = shotcrete.config.default_config_path().parents[1] / "data" / "profiles" / "horseshoe.csv"


def _vertices(path):
    return [(v.y_m, v.z_m, v.bulge) for v in _core.read_section_csv(str(path))]


def _arc_length(verts):
    """Closed form from the vertices and bulges (independent of the core's flattening)."""
    total = 0.0
    for (y0, z0, b), (y1, z1, _) in zip(verts, verts[1:]):
        chord = math.hypot(y1 - y0, z1 - z0)
        angle = 4.0 * math.atan(b)
        total += chord if b == 0 else chord / (2.0 * math.sin(angle / 2.0)) * angle
    return total


def _dxf(path, verts, scale=1000.0, origin=(1000.0, 2000.0), closed=False, extra=False):
    import ezdxf

    doc = ezdxf.new()
    msp = doc.modelspace()
    pts = [(origin[0] + y * scale, origin[1] + z * scale, b) for y, z, b in verts]
    msp.add_lwpolyline(pts, format="xyb", close=closed, dxfattribs={"layer": "SECTION"})
    if extra:
        msp.add_lwpolyline([(0, 0), (1, 1)], dxfattribs={"layer": "OTHER"})
    doc.saveas(path)
    return path


def test_section_cli_converts_a_dxf_drawn_in_mm(tmp_path, run_cli):
    verts = _vertices(HORSESHOE)
    dxf = _dxf(tmp_path / "horseshoe.dxf", verts)
    out, fig = tmp_path / "section.csv", tmp_path / "section.png"
    r = run_cli("section", dxf, "--units", "mm", "--origin", "1000,2000", "--out", out, "--plot", fig, "--json")
    assert r.exit_code == 0, r.output
    facts = json.loads(r.output)
    assert np.allclose(_vertices(out), verts, atol=1e-6)
    assert facts["arc_length_m"] == pytest.approx(_arc_length(verts), abs=1e-3)
    assert facts["theta_min_deg"] == pytest.approx(math.degrees(math.atan2(verts[0][1], verts[0][0])), abs=1e-6)
    assert fig.stat().st_size > 10000
    # Mirrored: the same line for a symmetric section, given the other way round.
    r = run_cli("section", dxf, "--units", "mm", "--origin", "1000,2000", "--mirror", "--json")
    assert r.exit_code == 0 and json.loads(r.output)["arc_length_m"] == pytest.approx(facts["arc_length_m"], abs=1e-6)
    # The written file is never overwritten without --force; the input never.
    r = run_cli("section", dxf, "--units", "mm", "--origin", "1000,2000", "--out", out)
    assert r.exit_code == 2 and "exists" in r.output
    r = run_cli("section", HORSESHOE, "--out", HORSESHOE, "--force")
    assert r.exit_code == 2 and "input" in r.output


@pytest.mark.parametrize("case, message", [
    ("closed", "closed"),
    ("two", "2 polylines"),
    ("not_dxf", "not a readable DXF"),
    ("origin", "not star-shaped"),   # the axis placed outside the section
    ("csv", "line 3"),
])
def test_section_cli_refuses_what_cannot_be_a_section(tmp_path, run_cli, case, message):
    verts = _vertices(HORSESHOE)
    args = ["--units", "mm", "--origin", "1000,2000"]
    if case == "closed":
        path = _dxf(tmp_path / "c.dxf", verts, closed=True)
    elif case == "two":
        path = _dxf(tmp_path / "t.dxf", verts, extra=True)
    elif case == "not_dxf":
        path = tmp_path / "n.dxf"
        path.write_text("this is not a drawing\n")
    elif case == "origin":
        path = _dxf(tmp_path / "o.dxf", verts)
        args = ["--units", "mm", "--origin", "1000,9000"]
    else:
        path = tmp_path / "bad.csv"
        path.write_text("y_m,z_m,bulge\n5.6,0,1\n-5.6,zero,0\n")
        args = []
    r = run_cli("section", path, *args)
    assert r.exit_code == 2 and message in r.output, r.output
    # The layer picks one polyline among several.
    if case == "two":
        assert run_cli("section", path, *args, "--layer", "SECTION").exit_code == 0


def test_plan_on_a_horseshoe_side_wall(tmp_path, run_cli):
    """A slice of the horseshoe's right side wall, below and above the springline: TD per cell is
    the generator's TD along the section's normal, and the nozzle sprays square to the section
    (not along the ray from the axis). The slice is short and narrow (0.6 m x 54 deg): as on the
    circle's slice, a few cells at its ends are out of the passes' reach, which the report says
    (exit 3, unreachable_cells); nothing else may be wrong."""
    cfg = tmp_path / "hs.yaml"
    cfg.write_text(f"profile:\n  section_path: {HORSESHOE}\n"
                   f"synth:\n  section_path: {HORSESHOE}\n  theta_min_rad: -0.35\n  theta_max_rad: 0.6\n"
                   "  length_m: 0.6\n  points_per_cell: 8\nplanner:\n  max_rounds: 3\nclearance:\n  enabled: false\n")
    out = tmp_path / "job"
    r = run_cli("demo", "--config", cfg, "--out", out, "--json")
    assert r.exit_code in (0, 3), r.output
    rep = json.loads((out / "report.json").read_text())
    assert {p["code"] for p in rep["problems"]} <= {"unreachable_cells"}
    assert (r.exit_code == 3) == bool(rep["problems"]) and rep["unreachable_cells"] < 20
    assert rep["design_profile"]["shape"] == "section" and rep["design_profile"]["section_path"] == str(HORSESHOE)
    assert rep["design_profile"]["theta_min_deg"] == pytest.approx(-20.254, abs=1e-3)
    config = shotcrete.load_config(cfg)
    bay = _core.make_synthetic_bay(config.synth)
    with open(out / "cells.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    err = [float(c["td_before_mm"]) - 1000.0 * bay.td_at(float(c["d_m"]), float(c["theta_rad"])) for c in rows]
    assert len(rows) == rep["cells"] > 300
    assert np.sqrt(np.mean(np.square(err))) < 5.0  # 5 mm scanner noise over ~8 points, pits curved in a cell
    assert rep["levels_after"].get("0", 0) > 0.9 * rep["cells"]
    # Nozzle square to the section: on the side wall below the springline the section's normal
    # tilts up to 9 deg from the ray; the spraying samples follow the normal within 2 deg.
    tr = np.load(out / "trajectory.npz")
    spray = tr["spraying"].astype(bool)
    pos, ax = tr["nozzle_position_m"][spray], tr["nozzle_axis"][spray]
    profile = _core.design_profile_from_config(config.profile)
    target = pos + ax  # about one standoff ahead
    th = np.arctan2(target[:, 2], target[:, 1])
    normals = np.array([profile.normal_at(t) for t in th])
    cos = np.einsum("ij,ij->i", ax[:, 1:] / np.linalg.norm(ax[:, 1:], axis=1, keepdims=True), normals)
    tilt = np.array([math.degrees(math.acos(profile.normal_cos_at(t))) for t in th])
    assert tilt.max() > 5.0  # the case is one where ray and normal differ
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 2.0


def _turned(xyz, yaw, grade, offset):
    """Rotate about z by yaw, tilt the axis up by the grade (about the y axis), then offset."""
    pitch = -math.atan(grade)
    rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
    ry = np.array([[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0], [-math.sin(pitch), 0, math.cos(pitch)]])
    return np.asarray(xyz) @ (rz @ ry).T + offset, rz @ ry


def test_alignment_in_survey_coordinates_gives_the_axis_the_bay_was_built_on(tmp_path, run_cli, small_config, small_cloud):
    """A bay turned 30 deg, on a 5 % grade, in survey coordinates, with the alignment the survey
    gives (chainage 1000 m at the bay's start): the job's axis is the bay's own, so the grid, TD
    and required volume equal the bay's at the origin; report.json says where on the alignment."""
    offset = np.array([500000.0, 4000000.0, 300.0])
    xyz, rot = _turned(small_cloud.xyz, math.radians(30), 0.05, offset)
    ply = tmp_path / "geo.ply"
    shotcrete.write_cloud(ply, shotcrete.Cloud(xyz))
    chain = np.arange(-20.0, 21.0, 1.0)
    axis_pts, _ = _turned(np.c_[chain, np.zeros_like(chain), np.zeros_like(chain)], math.radians(30), 0.05, offset)
    align = tmp_path / "alignment.csv"
    align.write_text("chainage_m,x_m,y_m,z_m\n" + "".join(f"{1000 + c:.3f},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f}\n"
                                                         for c, p in zip(chain, axis_pts)))
    base = rot @ np.asarray(small_config.robot.base_position_m) + offset
    common = ("synth:\n  theta_min_rad: 1.0\n  theta_max_rad: 2.0\n  length_m: 0.6\n"
              "planner:\n  max_rounds: 1\nclearance:\n  enabled: false\n")
    geo_cfg, ref_cfg = tmp_path / "geo.yaml", tmp_path / "ref.yaml"
    geo_cfg.write_text(common + f"profile:\n  alignment_path: {align}\n"
                       f"robot:\n  base_position_m: [{base[0]:.6f}, {base[1]:.6f}, {base[2]:.6f}]\n")
    ref_cfg.write_text(common)
    ref_ply = tmp_path / "ref.ply"
    shotcrete.write_cloud(ref_ply, small_cloud)
    reps = {}
    for name, cloud, cfg in (("geo", ply, geo_cfg), ("ref", ref_ply, ref_cfg)):
        r = run_cli("plan", cloud, "--config", cfg, "--out", tmp_path / name, "--json")
        assert r.exit_code in (0, 3), r.output
        reps[name] = json.loads((tmp_path / name / "report.json").read_text())
    geo, ref = reps["geo"], reps["ref"]
    at = geo["alignment"]
    assert at["path"] == str(align) and at["deviation_m"] < 1e-6
    # The section through the scan's centre: the bay's middle, chainage 1000 + 0.3 m.
    assert at["chainage_m"] == pytest.approx(1000.3, abs=0.02)
    # The CSV holds 0.1 mm: over the scan's span of the alignment that is a few thousandths of a degree.
    assert np.degrees(np.arccos(np.clip(np.dot(geo["axis"]["direction"], rot[:, 0]), -1, 1))) < 0.01
    # The same grid, to a cell at its rim (the axis is the bay's to the CSV's 0.1 mm).
    assert abs(geo["cells"] - ref["cells"]) <= 3 and geo["grid_shape"] == ref["grid_shape"]
    assert geo["required_volume_m3"] == pytest.approx(ref["required_volume_m3"], rel=3e-3)  # the rim cells
    assert geo["td_before_mm"]["mean"] == pytest.approx(ref["td_before_mm"]["mean"], abs=0.5)
    # The alignment and an estimated axis are two answers to one question: refused together.
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"profile:\n  alignment_path: {align}\n  estimate_axis: true\n")
    r = run_cli("plan", ply, "--config", bad, "--out", tmp_path / "bad")
    assert r.exit_code == 2 and "alignment_path" in r.output
    far = tmp_path / "far.yaml"
    far.write_text(f"profile:\n  alignment_path: {align}\n")
    r = run_cli("plan", ref_ply, "--config", far, "--out", tmp_path / "far")
    assert r.exit_code == 2 and "from the alignment" in r.output
