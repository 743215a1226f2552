"""Ordering benchmark: link length and time per method on bay-like raster instances.

Instances: n regions whose rasters run along the tunnel axis on the unrolled bay (arc 17.6 m x
1.2 m bay), mapped to 3-D on a 5.6 m half cylinder. Two layouts:
  full    - every raster spans the 1.2 m bay (the design's layout), random arc position;
  partial - rasters of random length 0.2-1.2 m at random places in the bay (regions of any size).
Reference: the exact optimum where n <= 16, else the best length found by any run here, including
a long reference run (hybrid ACO, 1000 iterations, 3 seeds). Gap = length / reference - 1.

    python bench/bench_ordering.py --out bench/results     # writes bench/results/ordering.json
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

import shotcrete
from shotcrete import _core

RADIUS_M, ARC_M, BAY_M = 5.6, 17.6, 1.2
SIZES = (10, 16, 20, 50, 100)
SOLVER_SEEDS = (1, 2, 3)


def bay_instance(n: int, seed: int, layout: str) -> "_core.OrderingProblem":
    rng = np.random.default_rng(seed)
    arc = rng.uniform(0.0, ARC_M, n)
    if layout == "full":
        d0, d1 = np.zeros(n), np.full(n, BAY_M)
    else:
        length = rng.uniform(0.2, BAY_M, n)
        d0 = rng.uniform(0.0, BAY_M - length)
        d1 = d0 + length
    flip = rng.random(n) < 0.5  # A/B labels in no particular order
    d0, d1 = np.where(flip, d1, d0), np.where(flip, d0, d1)
    theta = arc / RADIUS_M

    def to3d(d):
        return np.column_stack([d, RADIUS_M * np.cos(theta), RADIUS_M * np.sin(theta)])

    return _core.OrderingProblem(to3d(d0), to3d(d1))


def methods(n: int):
    """name -> (method, ga preset, local search)."""
    m = {"nn": ("nn", None, False), "nn+ls": ("nn", None, True),
         "ga_a": ("ga", "a", False), "ga_b": ("ga", "b", False), "ga_a+ls": ("ga", "a", True),
         "aco": ("aco", None, False), "aco+ls": ("aco", None, True), "best": ("best", None, True)}
    if n <= 16:
        m["exact"] = ("exact", None, False)
    return m


def run(problem, method, preset, local_search, seed):
    cfg = shotcrete.load_config().ordering
    cfg.method, cfg.seed, cfg.local_search = method, seed, local_search
    if preset:
        _core.apply_ga_preset(cfg, preset)
    t0, c0 = time.perf_counter(), time.process_time()
    r = _core.solve_ordering(problem, cfg)
    return r.link_length_m, time.perf_counter() - t0, time.process_time() - c0


def reference_run(problem):
    cfg = shotcrete.load_config().ordering
    cfg.method, cfg.aco_iterations, cfg.local_search = "aco", 1000, True
    best = float("inf")
    for seed in (101, 102, 103):
        cfg.seed = seed
        best = min(best, _core.solve_ordering(problem, cfg).link_length_m)
    return best


def bench(layouts=("full", "partial"), instance_seeds=(1, 2, 3)) -> dict:
    rows = []
    for layout in layouts:
        for n in SIZES:
            for inst_seed in instance_seeds:
                problem = bay_instance(n, 1000 * n + inst_seed, layout)
                results = {}
                for name, (method, preset, ls) in methods(n).items():
                    seeds = (1,) if method in ("nn", "exact") or (method == "best" and n <= 16) else SOLVER_SEEDS
                    runs = [run(problem, method, preset, ls, s) for s in seeds]
                    results[name] = {"link_length_m": [r[0] for r in runs], "solve_time_s": [r[1] for r in runs],
                                     "cpu_time_s": [r[2] for r in runs]}
                if n <= 16:
                    ref, kind = results["exact"]["link_length_m"][0], "exact"
                else:
                    found = min(min(v["link_length_m"]) for v in results.values())
                    ref, kind = min(found, reference_run(problem)), "best_found"
                for v in results.values():
                    gaps = [100.0 * (x / ref - 1.0) for x in v["link_length_m"]]
                    v.update(gap_pct_mean=statistics.fmean(gaps), gap_pct_max=max(gaps),
                             time_s_mean=statistics.fmean(v["solve_time_s"]), time_s_max=max(v["solve_time_s"]),
                             cpu_s_mean=statistics.fmean(v["cpu_time_s"]), cpu_s_max=max(v["cpu_time_s"]))
                rows.append({"layout": layout, "n": n, "instance_seed": inst_seed,
                             "reference": {"kind": kind, "link_length_m": ref}, "methods": results})
                print(f"{layout:7s} n={n:3d} inst={inst_seed} ref={ref:7.3f} ({kind}) " +
                      " ".join(f"{k}={v['gap_pct_mean']:.2f}%/{v['time_s_mean']:.3f}s" for k, v in results.items()),
                      flush=True)
    return {"instances": rows, "summary": summarise(rows)}


def summarise(rows) -> dict:
    out = {}
    for layout in sorted({r["layout"] for r in rows}):
        per_n = {}
        for n in SIZES:
            sel = [r for r in rows if r["layout"] == layout and r["n"] == n]
            names = sel[0]["methods"].keys()
            per_n[str(n)] = {
                name: {"gap_pct_mean": statistics.fmean(r["methods"][name]["gap_pct_mean"] for r in sel),
                       "gap_pct_max": max(r["methods"][name]["gap_pct_max"] for r in sel),
                       "time_s_mean": statistics.fmean(r["methods"][name]["time_s_mean"] for r in sel),
                       "time_s_max": max(r["methods"][name]["time_s_max"] for r in sel),
                       "cpu_s_max": max(r["methods"][name]["cpu_s_max"] for r in sel)}
                for name in names}
        out[layout] = per_n
    small = [r for r in rows if r["n"] <= 16]
    n100 = [r for r in rows if r["n"] == 100]
    out["targets"] = {
        "exact_n_le_16_time_s_max": max(r["methods"]["exact"]["time_s_max"] for r in small),
        "best_n_le_16_gap_pct_max": max(r["methods"]["best"]["gap_pct_max"] for r in small),
        "best_n100_gap_pct_max": max(r["methods"]["best"]["gap_pct_max"] for r in n100),
        "best_n100_time_s_max": max(r["methods"]["best"]["time_s_max"] for r in n100),
        "best_n100_cpu_s_max": max(r["methods"]["best"]["cpu_s_max"] for r in n100),
        "aco_n100_time_s_max": max(r["methods"]["aco"]["time_s_max"] for r in n100),
        "aco_n100_cpu_s_max": max(r["methods"]["aco"]["cpu_s_max"] for r in n100),
        "exact_n_le_16_cpu_s_max": max(r["methods"]["exact"]["cpu_s_max"] for r in small),
        "goal": "optimum for n <= 16 in < 1 s; n = 100 within 1 % of the best known in < 1 s",
    }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("bench/results"), help="output directory")
    ap.add_argument("--quick", action="store_true", help="one instance per size, full layout only")
    args = ap.parse_args()
    t0 = time.perf_counter()
    data = bench(("full",), (1,)) if args.quick else bench()
    data["meta"] = {"benchmark": "ordering", "machine": platform.machine(), "python": platform.python_version(),
                    "solver_seeds": list(SOLVER_SEEDS), "wall_s": time.perf_counter() - t0,
                    "load_average": list(os.getloadavg()),
                    "note": "solve_time_s: wall clock; cpu_time_s: process CPU (solvers are single-threaded); "
                            "the machine is shared, so wall times can be inflated by the load"}
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "ordering.json"
    path.write_text(json.dumps(data, indent=1))
    print(json.dumps(data["summary"]["targets"], indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
