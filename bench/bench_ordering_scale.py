"""Ordering at scale: the default method (best; from 150 regions the scalable path nn+ils) against
nearest neighbour on 200, 1,000 and 2,000 regions of the bay-like instances of bench_ordering.py
(partial rasters, and full rasters across the bay). Per run: wall and CPU time of the solve, tour
length, and its ratio to NN (quality figure; < 1 is shorter). Goal: 2,000 regions in <= 10 s.

    python bench/bench_ordering_scale.py --out bench/results    # writes bench/results/ordering_scale.json
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import shotcrete
from shotcrete import _core
from bench_ordering import bay_instance

SIZES = (200, 1000, 2000)
METHODS = {"nn": ("nn", False), "nn+ls": ("nn", True), "best": ("best", True)}


def run(problem, method: str, local_search: bool) -> dict:
    cfg = shotcrete.load_config().ordering
    cfg.method, cfg.local_search = method, local_search
    t0, c0 = time.perf_counter(), time.process_time()
    r = _core.solve_ordering(problem, cfg)
    return {"method": r.method, "link_length_m": r.link_length_m, "wall_s": time.perf_counter() - t0,
            "cpu_s": time.process_time() - c0, "time_budget_s": cfg.time_budget_s}


def bench(instance_seeds=(1, 2)) -> dict:
    rows = []
    for layout in ("partial", "full"):
        for n in SIZES:
            for seed in instance_seeds:
                problem = bay_instance(n, 7000 + 10 * n + seed, layout)
                res = {name: run(problem, m, ls) for name, (m, ls) in METHODS.items()}
                nn = res["nn"]["link_length_m"]
                for v in res.values():
                    v["ratio_to_nn"] = v["link_length_m"] / nn if nn > 0 else 1.0
                rows.append({"layout": layout, "n": n, "instance_seed": seed, "methods": res,
                             "load_average": list(os.getloadavg())})
                print(f"{layout:7s} n={n:4d} seed={seed} " + " ".join(
                    f"{k}={v['link_length_m']:.2f}m ({v['ratio_to_nn']:.3f} NN, {v['wall_s']:.2f}s wall, "
                    f"{v['cpu_s']:.2f}s cpu)" for k, v in res.items()), flush=True)
    summary = {}
    for layout in ("partial", "full"):
        for n in SIZES:
            sel = [r["methods"] for r in rows if r["layout"] == layout and r["n"] == n]
            summary[f"{layout}_{n}"] = {name: {
                "ratio_to_nn_mean": statistics.fmean(s[name]["ratio_to_nn"] for s in sel),
                "wall_s_max": max(s[name]["wall_s"] for s in sel),
                "cpu_s_max": max(s[name]["cpu_s"] for s in sel)} for name in METHODS}
    big = [r["methods"]["best"] for r in rows if r["n"] == 2000]
    summary["targets"] = {"best_n2000_wall_s_max": max(b["wall_s"] for b in big),
                          "best_n2000_cpu_s_max": max(b["cpu_s"] for b in big),
                          "best_n2000_partial_ratio_to_nn": summary["partial_2000"]["best"]["ratio_to_nn_mean"],
                          "goal": "2,000 regions (default method) in <= 10 s, shorter than NN"}
    return {"instances": rows, "summary": summary}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("bench/results"), help="output directory")
    args = ap.parse_args()
    t0 = time.perf_counter()
    data = bench()
    data["meta"] = {"benchmark": "ordering_scale", "machine": platform.machine(),
                    "python": platform.python_version(), "wall_s": time.perf_counter() - t0,
                    "load_average": list(os.getloadavg()),
                    "note": "wall_s: wall clock of the solve; cpu_s: process CPU (single-threaded solver); the "
                            "machine may be shared, so wall times can be inflated by the load"}
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "ordering_scale.json"
    path.write_text(json.dumps(data, indent=1))
    print(json.dumps(data["summary"]["targets"], indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
