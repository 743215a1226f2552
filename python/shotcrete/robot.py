"""The spraying manipulator: its URDF, the model loaded for a config, and the IK benchmark and
reachability figures of ``shotcrete robot`` and bench/bench_ik.py.

All numbers come from the C++ core (``_core.ik_benchmark``, ``_core.reachability_map``); this
module picks the URDF, puts results into plain dicts and draws the reachability map.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from . import _core
from .config import _data_file, load_config

URDF_NAME = "shotcrete_manipulator.urdf"


def urdf_path(config=None) -> Path:
    """config.robot.urdf_path if set, else the URDF installed with the package (or the source tree's)."""
    if config is not None and config.robot.urdf_path:
        path = Path(config.robot.urdf_path)
        if not path.is_file():
            raise ValueError(f"robot.urdf_path {path} does not exist")
        return path
    return _data_file(URDF_NAME)


def load_robot(config=None):
    """The manipulator of ``config`` (default config if None), placed at robot.base_position_m."""
    config = config or load_config()
    return _core.Robot.load_file(str(urdf_path(config)), np.asarray(config.robot.base_position_m, dtype=float))


def robot_summary(robot) -> dict:
    joints = []
    for i, name in enumerate(robot.joint_names):
        prismatic = bool(robot.joint_is_prismatic[i])
        joints.append({"name": name, "type": "prismatic" if prismatic else "revolute",
                       "unit": "m" if prismatic else "rad",
                       "lower": float(robot.lower_limits[i]), "upper": float(robot.upper_limits[i]),
                       "velocity": float(robot.velocity_limits[i]),
                       "acceleration": float(robot.acceleration_limits[i]),
                       "neutral": float(robot.neutral()[i]), "stow": float(robot.stow()[i])})
    return {"urdf": robot.urdf_path, "dof": robot.dof, "max_reach_m": robot.max_reach_m, "joints": joints}


def _stats_ms(times_s) -> dict:
    t = np.asarray(times_s, dtype=float) * 1000.0
    return {"median_ms": float(np.median(t)), "mean_ms": float(np.mean(t)), "p95_ms": float(np.percentile(t, 95)),
            "max_ms": float(np.max(t))}


def ik_bench(config, samples: int = 1000, seed: int = 1) -> dict:
    """Solve rates and times on random reachable poses: ours (5-DOF) vs plain KDL NR_JL (6-DOF)."""
    if samples < 1:
        raise ValueError(f"samples must be >= 1, got {samples}")
    robot = load_robot(config)
    b = _core.ik_benchmark(robot, config.robot, samples, seed)
    n = b.samples

    def method(solved, times, what):
        return {"what": what, "solved": int(solved), "solve_rate": solved / n, **_stats_ms(times)}

    return {
        "samples": n, "seed": seed,
        "tolerance": {"position_m": config.robot.ik_position_tolerance_m,
                      "angle_rad": config.robot.ik_angle_tolerance_rad},
        "ours_5dof_neutral_seed": method(b.solved_5dof_neutral, b.time_5dof_neutral_s,
                                         "DLS 5-DOF + null space + restarts, seed = neutral"),
        "ours_5dof_random_seed": method(b.solved_5dof_random_seed, b.time_5dof_random_seed_s,
                                        "DLS 5-DOF + null space + restarts, random seed"),
        "ours_5dof_no_restarts": method(b.solved_5dof_no_restart, b.time_5dof_no_restart_s,
                                        "DLS 5-DOF, one attempt from neutral"),
        "kdl_nr_jl_6dof": method(b.solved_kdl_6dof, b.time_kdl_6dof_s,
                                 "KDL ChainIkSolverPos_NR_JL on the full pose, seed = neutral"),
        "limit_violations": int(b.limit_violations), "tolerance_misses": int(b.tolerance_misses),
        "max_position_error_m": b.max_position_error_m, "max_angle_error_deg": math.degrees(b.max_angle_error_rad),
    }


def reach(config, radius_m: float, standoff_m: float = 1.0, bay_length_m: float = 1.2, n_theta: int = 61,
          n_d: int = 13):
    """(summary dict, ReachMap) for one tunnel radius."""
    robot = load_robot(config)
    m = _core.reachability_map(robot, config.robot, radius_m, standoff_m, bay_length_m, n_theta, n_d)
    reached = np.asarray(m.reached) > 0
    pos = np.asarray(m.position_error_m)
    ang = np.asarray(m.angle_error_rad)
    margin = np.asarray(m.min_limit_margin)
    summary = {
        "radius_m": radius_m, "standoff_m": standoff_m, "bay_length_m": bay_length_m,
        "n_theta": n_theta, "n_d": n_d, "reached": int(m.n_reached), "total": int(m.n_total),
        "fraction": m.fraction(),
        "max_position_error_mm": float(np.max(pos[reached]) * 1000.0) if reached.any() else None,
        "max_angle_error_deg": float(np.degrees(np.max(ang[reached]))) if reached.any() else None,
        "min_limit_margin": float(np.min(margin[reached])) if reached.any() else None,
        "unreached_theta_deg": sorted({round(math.degrees(float(m.theta_rad[i])), 1)
                                       for i, _ in zip(*np.nonzero(~reached))}),
    }
    return summary, m


def reach_figure(maps, path: Path) -> Path:
    """Cross-section of each tunnel with reached/unreached nozzle points, plus the limit margin map."""
    from . import plots  # here, not at the top: `import shotcrete` stays free of matplotlib

    plt = plots.plt

    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5))
    ax = axes[0]
    for m in maps:
        th = np.asarray(m.theta_rad)
        r = m.radius_m
        ax.plot(r * np.cos(th), r * np.sin(th), color="0.6", lw=1)
        ok = (np.asarray(m.reached) > 0).all(axis=1)
        rn = r - m.standoff_m
        ax.scatter(rn * np.cos(th[ok]), rn * np.sin(th[ok]), s=8, color="tab:green")
        if (~ok).any():
            ax.scatter(rn * np.cos(th[~ok]), rn * np.sin(th[~ok]), s=14, color="tab:red", marker="x")
    ax.axhline(-1.2, color="k", lw=0.8)
    ax.set_aspect("equal")
    ax.set_xlabel("y across [m]")
    ax.set_ylabel("z up [m]")
    ax.set_title("nozzle points at 1 m standoff (green: whole bay reached, red x: not)")
    ax = axes[1]
    for m in maps:
        margin = np.asarray(m.min_limit_margin)
        ax.plot(np.degrees(np.asarray(m.theta_rad)), np.nanmin(margin, axis=1), label=f"R = {m.radius_m:g} m")
    ax.set_xlabel("theta [deg] (0 = right springline, 90 = crown)")
    ax.set_ylabel("worst joint-limit margin over the bay [share of range]")
    ax.set_title(f"reachability, bay d in [0, {maps[0].d_m[-1]:g}] m")
    ax.legend()
    return plots.save(fig, path)
