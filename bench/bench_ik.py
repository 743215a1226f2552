"""IK benchmark and reachability: writes <out>/ik.json (and <out>/reach.png).

    python bench/bench_ik.py --out bench/results [--samples 2000]
"""
from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

from shotcrete.robot import ik_bench, load_robot, reach, reach_figure, robot_summary
from shotcrete.config import load_config


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=Path("bench/results"))
    ap.add_argument("--samples", type=int, default=2000)
    args = ap.parse_args()
    config = load_config()
    t0 = time.perf_counter()
    result = {"robot": robot_summary(load_robot(config)), "ik": ik_bench(config, args.samples, seed=1)}
    maps, radii = [], []
    for radius in (5.0, 5.6, 6.5, 8.0):
        summary, m = reach(config, radius, 1.0, 1.2, 61, 13)
        radii.append(summary)
        maps.append(m)
    args.out.mkdir(parents=True, exist_ok=True)
    fig = reach_figure(maps, args.out / "reach.png")
    result["reachability"] = {"radii": radii, "figure": str(fig)}
    result["targets"] = {"solve_rate_min": 0.995, "median_ms_max": 1.0,
                         "met": result["ik"]["ours_5dof_neutral_seed"]["solve_rate"] >= 0.995
                         and result["ik"]["ours_5dof_neutral_seed"]["median_ms"] < 1.0
                         and all(r["fraction"] == 1.0 for r in radii)}
    result["machine"] = platform.platform()
    result["wall_time_s"] = time.perf_counter() - t0
    (args.out / "ik.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({"ik": {k: v for k, v in result["ik"].items() if isinstance(v, dict)},
                      "reach": [(r["radius_m"], r["fraction"]) for r in radii]}, indent=1))


if __name__ == "__main__":
    main()
