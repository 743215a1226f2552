"""The full-trajectory clearance check alone (issue 18's "<= 2 s on 2 cores"), on a saved trajectory.

    python bench/bench_clearance_check.py --save bench/results/default_bay_trajectory.npz   # plan once
    python bench/bench_clearance_check.py --trajectory bench/results/default_bay_trajectory.npz [--repeats 5]

--save plans the default bay as `shotcrete demo` does (the config's defaults, plan_for_arm with the
clearance check) and saves the kept trajectory's times and joints and the wall the check uses
(arm_wall: the scan's points and the executed deposit's surface). Without it, check_clearance runs
`--repeats` times on the saved trajectory: wall time (the core's own timing), CPU time of the process
over the check (both threads), the 1-minute load average before each run, the queries and each
link's least distance. Writes <out>/clearance_check.json. The instruction count independent of the
machine's load: run one repeat under valgrind --tool=callgrind (see docs/architecture.md §9).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import time
from pathlib import Path

import numpy as np

from shotcrete import _core, synthetic_cloud
from shotcrete.config import load_config
from shotcrete.robot import load_robot


def cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def save(path: Path) -> None:
    cfg = load_config()
    robot = load_robot(cfg)
    surface = _core.build_surface(synthetic_cloud(cfg), cfg)
    arm = _core.plan_for_arm(surface, cfg, robot)
    tr = arm.trajectory
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, t_s=np.asarray(tr.t_s), q=np.asarray(tr.q), wall=np.asarray(_core.arm_wall(surface, arm.executed)),
                        resolution_m=cfg.clearance.octree_resolution_m)
    print(f"saved {path}: {len(tr.t_s)} samples, {arm.clearance.wall_points} wall points, check {arm.clearance.seconds:.2f} s")


def run(path: Path, repeats: int) -> dict:
    cfg = load_config()
    robot = load_robot(cfg)
    data = np.load(path)
    tr = _core.TimedTrajectory.from_joints(data["t_s"].tolist(), data["q"])
    runs = []
    rep = None
    for _ in range(repeats):
        wall = _core.WallOctree(data["wall"], float(data["resolution_m"]))  # the field is built inside the check
        load = os.getloadavg()[0]
        c0, t0 = cpu_s(), time.perf_counter()
        rep = _core.check_clearance(robot, tr, wall, cfg.clearance)
        runs.append({"check_s": rep.seconds, "elapsed_s": time.perf_counter() - t0, "cpu_s": cpu_s() - c0,
                     "load_average_1min": load})
    return {
        "trajectory": str(path), "samples": rep.samples, "shapes": len(robot.collision_shapes),
        "wall_points": int(len(data["wall"])), "runs": runs,
        "check_s_min": min(r["check_s"] for r in runs), "cpu_s_min": min(r["cpu_s"] for r in runs),
        "field_queries": rep.field_queries, "exact_queries": rep.exact_queries, "self_queries": rep.self_queries,
        "samples_below_margin": rep.samples_below_margin,
        "links": {l.link: {"min_m": l.min_m, "at_time_s": l.at_time_s, "below": l.samples_below_margin} for l in rep.links},
        "self": {"pair": f"{rep.self_clearance.link_a}-{rep.self_clearance.link_b}", "min_m": rep.self_clearance.min_m},
        "target_s": 2.0, "threads": 2, "cores": os.cpu_count(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--save", type=Path, help="plan the default bay and save its trajectory and wall here (.npz)")
    ap.add_argument("--trajectory", type=Path, default=Path("bench/results/default_bay_trajectory.npz"))
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=Path("bench/results"))
    args = ap.parse_args()
    if args.save:
        save(args.save)
        return
    result = run(args.trajectory, args.repeats)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "clearance_check.json").write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
