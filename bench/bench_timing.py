"""Motion timing benchmark: one representative region (8 axial passes of 1.2 m, 0.2 m apart on the
5.6 m wall, nozzle at the configured standoff) timed four ways on the bundled robot, all checked in
joint space (finite-difference velocities / accelerations against the URDF limits):

- quintic baseline: quintic acceleration / deceleration, full stop at every pass end and step-over
  (design 7b), with the largest nozzle acceleration the joints allow (bisection);
- cycloid + arcs at that same acceleration (k1 = 1, k2 = 0): the gain of not stopping;
- cycloid + arcs with the config's parameters (may break limits: reported, not hidden);
- cycloid + arcs tuned by AIWCPSO (k1, k2, start/end length, turn speed).

Also a two-region plan with a joint-space transit (time_plan), and the whole default bay planned in
both modes and timed with the config's parameters (``demo_plan``): duration, the worst joint
velocity / acceleration ratios and the share of samples over the acceleration limit by segment kind;
then again with the per-region timing swarm (``with_timing_swarm``).
Writes <out>/timing.json.

    python bench/bench_timing.py --out bench/results
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

SPEEDS = (0.22, 0.30, 0.18, 0.26, 0.34, 0.20, 0.28, 0.24)  # m/s, as the deposition would set them


def axial_region(n, length, wall_spacing, x0, theta0, standoff, R=5.6, speeds=SPEEDS):
    rn = R - standoff
    passes = []
    for i in range(n):
        th = theta0 + i * wall_spacing / R
        f = np.linspace(0.0, 1.0, int(round(length / 0.01)) + 1)
        x = x0 + (f if i % 2 == 0 else 1.0 - f) * length
        pos = np.column_stack([x, np.full_like(x, rn * math.cos(th)), np.full_like(x, rn * math.sin(th))])
        passes.append({"positions": pos, "axes": np.array([0.0, math.cos(th), math.sin(th)]),
                       "speed_mps": speeds[i % len(speeds)]})
    return passes


def joint_summary(tr) -> dict:
    s = tr.summary()
    s["feasible"] = bool(s["max_velocity_ratio"] <= 1.0 + 1e-3 and s["max_acceleration_ratio"] <= 1.0 + 1e-3
                         and s["max_position_violation_rad"] <= 0.0 and s["max_position_violation_m"] <= 0.0)
    return s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=Path("bench/results"))
    args = ap.parse_args()
    cfg = load_config()
    tc, rc = cfg.timing, cfg.robot
    robot = load_robot(cfg)
    seed = robot.neutral()
    rate = tc.trajectory_rate_hz
    region = axial_region(8, 1.2, 0.2, 0.0, 1.1, cfg.planner.standoff_m)
    spray_s = sum(1.2 / p["speed_mps"] for p in region)
    vmean = float(np.mean([p["speed_mps"] for p in region]))
    result: dict = {"region": {"passes": 8, "pass_length_m": 1.2, "wall_spacing_m": 0.2, "wall_radius_m": 5.6,
                               "standoff_m": cfg.planner.standoff_m, "speeds_mps": list(SPEEDS),
                               "spray_time_s": spray_s},
                    "rate_hz": rate}

    # Quintic baseline: the largest nozzle acceleration whose joint trajectory stays within limits.
    def baseline(acc):
        path, prof = _core.quintic_baseline(region, acc, vmean)
        return path, prof, _core.time_path(robot, path, prof, seed, rate, rc)

    t0 = time.perf_counter()
    lo, hi = 0.02, tc.nozzle_max_accel_mps2
    _, _, tr = baseline(hi)
    if joint_summary(tr)["feasible"]:
        lo = hi
    else:
        for _ in range(20):
            mid = 0.5 * (lo + hi)
            if joint_summary(baseline(mid)[2])["feasible"]:
                lo = mid
            else:
                hi = mid
    a_base = lo
    _, prof_b, tr_b = baseline(a_base)
    result["quintic_baseline"] = {"accel_mps2": a_base, "stepover_speed_mps": vmean,
                                  "duration_s": prof_b.duration_s, "joint": joint_summary(tr_b),
                                  "search_s": time.perf_counter() - t0}

    def cycloid(params):
        path = _core.timing_region_path(region, params.start_length_m, params.end_length_m, tc)
        prof = _core.region_profile(path, params)
        tr = _core.time_path(robot, path, prof, seed, rate, rc)
        nozzle = _core.check_nozzle(path, prof, tc.nozzle_max_speed_mps, tc.nozzle_max_accel_mps2)
        return {"params": params.to_dict(), "duration_s": prof.duration_s, "joint": joint_summary(tr),
                "nozzle": nozzle}

    # Same peak acceleration as the baseline at the first / last pass: s = v^2 / a (k1 = 1, k2 = 0).
    same = _core.TimingParams()
    same.k1, same.k2 = 1.0, 0.0
    same.start_length_m = region[0]["speed_mps"] ** 2 / a_base
    same.end_length_m = region[-1]["speed_mps"] ** 2 / a_base
    same.turn_accel_mps2 = a_base  # the arcs' centripetal acceleration too
    result["cycloid_arcs_same_accel"] = cycloid(same)
    result["cycloid_arcs_config"] = cycloid(_core.TimingParams.from_config(tc))

    t0 = time.perf_counter()
    tun = _core.tune_timing(robot, [region], seed, tc, rc)
    tune_s = time.perf_counter() - t0
    pso = cycloid(tun.params[0])
    pso.update({"tune_s": tune_s, "swarm_duration_s": tun.duration_s, "evaluations": tun.pso[0].evaluations,
                "best_history_s": [h if h < 1e5 else None for h in tun.pso[0].best_history],
                "success_history": tun.pso[0].success_history,
                "particles": tc.pso_particles, "iterations": tc.pso_iterations})
    pso["swarm_feasible"] = bool(tun.feasible[0])
    result["cycloid_arcs_pso"] = pso

    tb = result["quintic_baseline"]["duration_s"]
    ts = result["cycloid_arcs_same_accel"]["duration_s"]
    tp = pso["duration_s"]
    result["savings"] = {
        "arcs_vs_quintic": 1.0 - ts / tb,
        "pso_vs_quintic": 1.0 - tp / tb,
        "pso_vs_arcs_same_accel": 1.0 - tp / ts,
        "paper": {"vs_quintic": 0.25, "pso_extra": 0.013},
    }

    # Two regions in order with the joint transit between them (the full time_plan path).
    region2 = axial_region(6, 1.0, 0.2, 0.1, 0.55, cfg.planner.standoff_m)
    t0 = time.perf_counter()
    tun2 = _core.tune_timing(robot, [region, region2], seed, tc, rc)
    tr2 = _core.time_plan(robot, [region, region2], seed, tc, rc, tun2.params)
    result["two_regions"] = {"duration_s": tr2.duration_s, "transit_time_s": tr2.transit_time_s,
                             "spray_time_s": tr2.spray_time_s, "samples": len(tr2), "joint": joint_summary(tr2),
                             "params": [p.to_dict() for p in tun2.params], "wall_time_s": time.perf_counter() - t0}
    result["demo_plan"] = {mode: demo_plan_timing(cfg, robot, mode) for mode in ("optimal", "graded")}
    result["machine"] = platform.platform()
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "timing.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: result[k] for k in ("savings",)}, indent=1))
    print(json.dumps({k: (v["duration_s"], v["joint"]["feasible"]) for k, v in result.items()
                      if isinstance(v, dict) and "joint" in v}, indent=1))


KINDS = ("pass", "turn", "lead", "link", "transit")


def demo_plan_timing(cfg, robot, mode):
    """The default synthetic bay planned for the arm in ``mode`` (plan_for_arm: joint-limited pass
    speeds, timing with the config's parameters, re-plans) next to the plan made without the arm
    and timed the same way."""
    cfg.planner.mode = mode
    surface = _core.build_surface(synthetic_cloud(cfg), cfg)
    valid = np.asarray(surface.grid.valid).reshape(-1)

    def figures(plan, tr, wall):
        ratio_a = (np.abs(tr.qdd) / np.asarray(robot.acceleration_limits)).max(axis=1)
        ratio_v = (np.abs(tr.qd) / np.asarray(robot.velocity_limits)).max(axis=1)
        kind = np.asarray(tr.kind)
        over = {name: {"samples": int((kind == k).sum()),
                       "over_accel_limit": int(((kind == k) & (ratio_a > 1.0)).sum()),
                       "over_velocity_limit": int(((kind == k) & (ratio_v > 1.0)).sum()),
                       "max_accel_ratio": float(ratio_a[kind == k].max()) if (kind == k).any() else 0.0,
                       "max_velocity_ratio": float(ratio_v[kind == k].max()) if (kind == k).any() else 0.0}
                for k, name in enumerate(KINDS)}
        regions = [list(r.passes) for rnd in plan.rounds for r in rnd.regions]
        td = np.asarray(plan.td_after_m)[valid] * 1000.0
        return {"regions": len(regions), "passes": sum(len(r) for r in regions), "duration_s": tr.duration_s,
                "plan_spray_time_s": plan.spray_time_s, "residual_rms_mm": float(np.sqrt(np.mean(td ** 2))),
                "speed_capped": int(plan.speed_capped),
                "spray_time_s": tr.spray_time_s, "transit_time_s": tr.transit_time_s,
                "max_velocity_ratio": tr.max_velocity_ratio, "max_acceleration_ratio": tr.max_acceleration_ratio,
                "share_over_accel_limit": float((ratio_a > 1.0).mean()), "untracked_regions": tr.untracked_regions,
                "by_kind": over, "wall_time_s": wall}

    t0 = time.perf_counter()
    free = _core.plan_bay(surface, cfg)
    regions = [list(r.passes) for rnd in free.rounds for r in rnd.regions]
    tr_free = _core.time_plan(robot, regions, robot.stow(), cfg.timing, cfg.robot)
    without = figures(free, tr_free, time.perf_counter() - t0)
    t0 = time.perf_counter()
    arm = _core.plan_for_arm(surface, cfg, robot)
    out = figures(arm.plan, arm.trajectory, time.perf_counter() - t0)
    out.update({"replans": arm.replans, "learned_speed_bounds": len(arm.learned.speed_mps),
                "planned_without_the_arm": without})
    # The same with the timing swarm (timing.tune_with_pso): per-region parameters, kept when faster.
    cfg.timing.tune_with_pso = True
    t0 = time.perf_counter()
    tuned = _core.plan_for_arm(surface, cfg, robot)
    cfg.timing.tune_with_pso = False
    swarm = figures(tuned.plan, tuned.trajectory, time.perf_counter() - t0)
    summary = _core.summarise_job(surface, tuned, robot, cfg).to_dict()["trajectory"]["swarm"]
    del summary["params"]
    swarm.update(summary)
    swarm["saving_vs_config_timing"] = 1.0 - tuned.trajectory.duration_s / tuned.config_duration_s
    out["with_timing_swarm"] = swarm
    return out


if __name__ == "__main__":
    main()
