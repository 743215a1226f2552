"""Robot bindings and CLI: FK against an independent FK from the URDF XML (ElementTree + numpy),
IK round trips, path errors, CLI JSON output."""
from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from typer.testing import CliRunner

import shotcrete
from shotcrete import _core
from shotcrete.cli import app
from shotcrete.robot import load_robot, urdf_path


def _rpy(r, p, y):
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _axis_angle(axis, angle):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def _reference_fk(path, q, base):
    joints = {j.find("child").get("link"): j for j in ET.parse(path).getroot().findall("joint")}
    chain, link = [], "nozzle_tip"
    while link != "base_link":
        j = joints[link]
        chain.insert(0, j)
        link = j.find("parent").get("link")
    T = np.eye(4)
    T[:3, 3] = base
    k = 0
    for j in chain:
        o = j.find("origin")
        xyz = [float(v) for v in o.get("xyz", "0 0 0").split()]
        rpy = [float(v) for v in o.get("rpy", "0 0 0").split()]
        O = np.eye(4)
        O[:3, :3] = _rpy(*rpy)
        O[:3, 3] = xyz
        T = T @ O
        if j.get("type") in ("revolute", "prismatic"):
            axis = [float(v) for v in j.find("axis").get("xyz").split()]
            M = np.eye(4)
            if j.get("type") == "revolute":
                M[:3, :3] = _axis_angle(axis, q[k])
            else:
                M[:3, 3] = np.asarray(axis) * q[k]
            T = T @ M
            k += 1
    return T


@pytest.fixture(scope="module")
def config():
    return shotcrete.load_config()


@pytest.fixture(scope="module")
def robot(config):
    return load_robot(config)


def test_loads_installed_urdf(robot):
    assert robot.dof == 8
    assert robot.joint_names[0] == "slew" and robot.joint_names[-1] == "nozzle_tilt"
    assert sum(robot.joint_is_prismatic) == 2
    assert np.all(robot.velocity_limits > 0) and np.all(robot.acceleration_limits > 0)
    assert robot.within_limits(robot.neutral())


def test_fk_matches_reference(robot, config):
    rng = np.random.default_rng(4)
    base = np.asarray(config.robot.base_position_m)
    for _ in range(50):
        q = rng.uniform(robot.lower_limits, robot.upper_limits)
        np.testing.assert_allclose(robot.fk(q), _reference_fk(urdf_path(config), q, base), atol=1e-9)


def test_ik_round_trip(robot, config):
    rng = np.random.default_rng(9)
    solved = 0
    for _ in range(100):
        T = robot.fk(rng.uniform(robot.lower_limits, robot.upper_limits))
        res = _core.solve_ik_5dof(robot, _core.NozzlePose(T[:3, 3], T[:3, 2]), robot.neutral(), config.robot)
        if res.success:
            solved += 1
            F = robot.fk(res.q)
            assert robot.within_limits(res.q)
            assert np.linalg.norm(F[:3, 3] - T[:3, 3]) <= config.robot.ik_position_tolerance_m
            assert math.acos(min(1.0, float(F[:3, 2] @ T[:3, 2]))) <= config.robot.ik_angle_tolerance_rad + 1e-9
    assert solved >= 98


def test_unreachable_path_raises_runtime_error(robot, config):
    poses = [_core.NozzlePose(np.array([0.3, 0.0, 4.0]), np.array([0.0, 0.0, 1.0])),
             _core.NozzlePose(np.array([0.3, 0.0, 30.0]), np.array([0.0, 0.0, 1.0]))]
    with pytest.raises(RuntimeError, match=r"waypoint 1 .*out of reach"):
        _core.solve_path(robot, poses, robot.neutral(), config.robot)


def test_cli_ik_bench_and_reach_json(tmp_path):
    runner = CliRunner()
    res = runner.invoke(app, ["robot", "ik-bench", "--samples", "50", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["samples"] == 50
    assert out["limit_violations"] == 0 and out["tolerance_misses"] == 0
    assert 0.0 <= out["kdl_nr_jl_6dof"]["solve_rate"] <= 1.0
    png = tmp_path / "reach.png"
    res = runner.invoke(app, ["robot", "reach", "--radius-m", "5.6", "--n-theta", "13", "--n-d", "3",
                              "--figure", str(png), "--json"])
    assert res.exit_code == 0, res.output
    r = json.loads(res.stdout)["radii"][0]
    assert r["total"] == 39 and r["reached"] == r["total"]
    assert png.stat().st_size > 1000


def test_cli_rejects_bad_input():
    res = CliRunner().invoke(app, ["robot", "ik-bench", "--samples", "0"])
    assert res.exit_code == 2
    res = CliRunner().invoke(app, ["robot", "reach", "--radius-m", "0.5"])
    assert res.exit_code == 2
