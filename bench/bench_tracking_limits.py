"""Joint tracking near the joint limits (issue 15, item 4): is q(s) a smooth function of the path
where the task drives joints to their limits?

Path: from the ready posture (URDF neutral), the nozzle pulled straight towards the shoulder with
its spray axis fixed, `--lengths` metres, sampled every 2 mm and every 1 mm; tracked by
`track_joint_path` at the limit gains `timing_joint_path` tries (0.02, 0.1, 0.3). Near 4 m both
telescopes retract to their lower limits (what the graded default bay does over a pit at the
upper left wall, seeds 1 and 3; docs/architecture.md §9).

Per case: the worst tracking error, the least normalised joint position (below 0: a joint past
its lower limit, which timing_joint_path refuses), the samples whose second difference flips sign
against both neighbours (|q''| > 1 per m^2: the path zig-zagging), the largest |q''| per joint
[joint unit / m^2] and its ratio between the 1 mm and the 2 mm sampling. A smooth q(s) gives the
same q'' at both samplings (ratio about 1); a zig-zag of one drift cap per sample, or a kink, gives
a q'' that grows as 1 / ds (ratio about 2). q'' v^2 is the joint acceleration at nozzle speed v.

Writes bench/results/tracking_limits.json.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from shotcrete import _core

GAINS = (0.02, 0.1, 0.3)
STEPS_M = (0.002, 0.001)


def track(robot, q0, start_m, direction, axis, length_m, step_m, gain):
    s = np.arange(0.0, length_m + 1e-9, step_m)
    poses = np.hstack([start_m[None, :] + s[:, None] * direction[None, :], np.repeat(axis[None, :], len(s), 0)])
    q, err_m, err_rad = _core.track_joint_path(robot, poses, q0, gain)
    return np.asarray(q), err_m, err_rad


def case(robot, q0, start_m, direction, axis, length_m, gain):
    lo, hi = np.asarray(robot.lower_limits), np.asarray(robot.upper_limits)
    names = list(robot.joint_names)
    out = {"length_m": length_m, "limit_gain": gain}
    worst = {}
    for step in STEPS_M:
        q, err_m, err_rad = track(robot, q0, start_m, direction, axis, length_m, step, gain)
        d2 = np.diff(q, 2, axis=0) / step**2
        big = np.abs(d2) > 1.0
        flips = (d2[1:-1] * d2[:-2] < 0) & (d2[1:-1] * d2[2:] < 0) & big[1:-1]
        x = (q - lo) / (hi - lo)
        key = f"{step * 1000:g}mm"
        worst[step] = np.abs(d2).max(axis=0)
        out[key] = {
            "max_error_m": float(err_m),
            "max_error_rad": float(err_rad),
            "least_normalised_position": {n: round(float(v), 5) for n, v in zip(names, x.min(axis=0))},
            "samples_at_or_past_a_limit": int(((x <= 1e-9) | (x >= 1 - 1e-9)).any(axis=1).sum()),
            "sign_flipping_samples": {n: int(v) for n, v in zip(names, flips.sum(axis=0))},
            "max_abs_qdd_per_m2": {n: round(float(v), 3) for n, v in zip(names, worst[step])},
        }
    ratio = worst[STEPS_M[1]] / np.maximum(worst[STEPS_M[0]], 1e-12)
    out["qdd_ratio_1mm_over_2mm"] = {n: round(float(v), 3) for n, v in zip(names, ratio)}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    parser.add_argument("--lengths", type=float, nargs="+", default=[4.0, 4.2])
    args = parser.parse_args()
    robot = _core.Robot.load(_core.RobotConfig())
    q0 = np.asarray(robot.neutral())
    T = np.asarray(robot.fk(q0))
    start, axis = T[:3, 3], T[:3, 2]
    to_shoulder = np.asarray(robot.shoulder_position) - start
    direction = to_shoulder / np.linalg.norm(to_shoulder)
    rows = []
    for length in args.lengths:
        for gain in GAINS:
            row = case(robot, q0, start, direction, axis, length, gain)
            rows.append(row)
            flips = sum(row["1mm"]["sign_flipping_samples"].values())
            print(f"length {length} m, gain {gain}: least x {min(row['1mm']['least_normalised_position'].values()):.5f}, "
                  f"sign flips {flips}, max |q''| {max(row['1mm']['max_abs_qdd_per_m2'].values()):.1f} /m^2 (1 mm), "
                  f"ratio 1mm/2mm {max(row['qdd_ratio_1mm_over_2mm'].values()):.2f}", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "tracking_limits.json"
    path.write_text(json.dumps({"path": "ready posture, nozzle pulled towards the shoulder, axis fixed",
                                "cases": rows}, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
