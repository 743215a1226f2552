"""Clearance benchmark (issue 18): the space allowance of the bundled arm along timed trajectories,
against an octree of the wall (FCL + octomap).

- accuracy: the octree distance of 10,000 random link poses (the URDF's collision cylinders, near the
  default wall) against the exact distance to the wall's points (brute force, numpy): how far short
  it reads (never long), against half a leaf diagonal;
- the default bay, both planner modes: samples below the margins, the least distance per link, the
  exact queries run and the wall-clock time of the whole-trajectory check;
- a narrow bay (design radius 4.5 m): the same.

Writes <out>/clearance.json.

    python bench/bench_clearance.py --out bench/results [--quick]
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path

import numpy as np

from shotcrete import _core, synthetic_cloud
from shotcrete.config import load_config
from shotcrete.robot import load_robot


def shape_distances_exact(points: np.ndarray, shape, pose: np.ndarray) -> float:
    """Exact distance of a collision cylinder (at its link's 4x4 pose) to a set of points, numpy."""
    T = pose @ np.asarray(shape.origin)
    local = (points - T[:3, 3]) @ T[:3, :3]  # points in the shape's frame
    radial = np.maximum(0.0, np.hypot(local[:, 0], local[:, 1]) - shape.radius_m)
    axial = np.maximum(0.0, np.abs(local[:, 2]) - 0.5 * shape.length_m)
    return float(np.min(np.hypot(radial, axial)))


def accuracy(cfg, n_poses: int, seed: int = 1) -> dict:
    cloud = synthetic_cloud(cfg)
    pts = np.asarray(cloud.xyz)
    robot = load_robot(cfg)
    shapes = [s for s in robot.collision_shapes if s.kind == _core.CollisionShape.Kind.cylinder]
    out = {}
    for res in (0.05, 0.02):
        tree = _core.WallOctree(pts, res)
        rng = np.random.default_rng(seed)
        shorts, t_query = [], 0.0
        for _ in range(n_poses):
            s = shapes[int(rng.integers(len(shapes)))]
            th, r = rng.uniform(0.2, math.pi - 0.2), rng.uniform(3.5, 5.3)
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            z = np.array([0.0, 0.0, 1.0])
            v = np.cross(z, axis)
            c = float(z @ axis)
            vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
            R = np.eye(3) + vx + vx @ vx / (1.0 + c) if c > -0.999 else np.diag([1.0, -1.0, -1.0])
            pose = np.eye(4)
            pose[:3, :3] = R @ np.asarray(s.origin)[:3, :3].T  # the cylinder's axis along `axis`
            pose[:3, 3] = [rng.uniform(0.1, 1.1), r * math.cos(th), r * math.sin(th)]
            pose[:3, 3] -= pose[:3, :3] @ np.asarray(s.origin)[:3, 3]
            t0 = time.perf_counter()
            d, _ = tree.distance(s, pose)
            t_query += time.perf_counter() - t0
            exact = shape_distances_exact(pts, s, pose)
            if exact > 0:
                shorts.append(exact - d)
        shorts = np.asarray(shorts)
        out[f"resolution_{res}"] = {
            "poses": n_poses, "leaves": tree.occupied_leaves,
            "short_mm": {"mean": float(shorts.mean() * 1e3), "p95": float(np.percentile(shorts, 95) * 1e3),
                         "max": float(shorts.max() * 1e3), "min": float(shorts.min() * 1e3)},
            "half_leaf_mm": res / 2 * 1e3, "half_leaf_diagonal_mm": math.sqrt(3) * res / 2 * 1e3,
            "never_long": bool(shorts.min() >= -1e-6),
            "query_ms_mean": t_query / n_poses * 1e3,
            "target": "reads <= half an octree cell short, never long",
        }
    return out


def bay(cfg, label: str) -> dict:
    robot = load_robot(cfg)
    cloud = synthetic_cloud(cfg)
    surface = _core.build_surface(cloud, cfg)
    cfg.clearance.enabled = False  # timed below, on its own
    t0 = time.perf_counter()
    arm = _core.plan_for_arm(surface, cfg, robot)
    t_plan = time.perf_counter() - t0
    if arm.trajectory is None:
        return {"label": label, "error": arm.timing_error}
    t0 = time.perf_counter()
    rep = _core.arm_clearance(surface, arm.trajectory, arm.executed, robot, cfg.clearance)
    t_all = time.perf_counter() - t0
    return {
        "label": label, "samples": rep.samples, "trajectory_s": arm.trajectory.duration_s,
        "samples_below_margin": rep.samples_below_margin,
        "links": {l.link: {"min_m": l.min_m, "margin_m": l.margin_m, "below": l.samples_below_margin}
                  for l in rep.links},
        "self": {"pair": f"{rep.self_clearance.link_a}-{rep.self_clearance.link_b}",
                 "min_m": rep.self_clearance.min_m, "below": rep.self_clearance.samples_below_margin},
        "wall_queries": rep.wall_queries, "self_queries": rep.self_queries,
        "queries_per_sample_and_shape": rep.wall_queries / max(1, rep.samples * len(robot.collision_shapes)),
        "octree_s": t_all - rep.seconds, "check_s": rep.seconds, "plan_s": t_plan, "wall_points": rep.wall_points,
        "target_check_s": 2.0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("bench/results"))
    ap.add_argument("--quick", action="store_true", help="1,000 poses, default bay in optimal mode only")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    result = {"machine": platform.machine(), "accuracy": accuracy(load_config(), 1000 if args.quick else 10000)}
    bays = []
    for mode in (["optimal"] if args.quick else ["optimal", "graded"]):
        cfg = load_config()
        cfg.planner.mode = mode
        bays.append(bay(cfg, f"default bay, {mode}"))
    if not args.quick:
        cfg = load_config()
        cfg.profile.design_radius_m = 4.5
        cfg.synth.design_radius_m = 4.5
        bays.append(bay(cfg, "narrow bay (design radius 4.5 m)"))
    result["bays"] = bays
    (args.out / "clearance.json").write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
