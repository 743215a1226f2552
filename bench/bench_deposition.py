"""Thickness of one 1.2 m pass (10 mm steps) on a 200,000-point synthetic bay (target: < 20 ms),
plus the stroke fit numbers and the default pass spacing."""
from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import time
from pathlib import Path

import numpy as np

import shotcrete
from shotcrete import _core
from shotcrete.deposition import fit_report, spacing_report

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, default=Path("bench/results"))
    parser.add_argument("--points", type=int, default=200_000)
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args()
    cfg = shotcrete.load_config()

    # Stroke fit of the shipped data.
    t0 = time.perf_counter()
    data = _core.read_stroke_csv(str(ROOT / "data" / "deposition_stroke.csv"), 1.0, 0.15,
                                 cfg.deposition.rebound_fraction)
    fit = _core.fit_stroke(data)
    fit_s = time.perf_counter() - t0

    # ~200k points on the default bay, normals from PCL k-NN.
    s = cfg.synth
    cells = (s.theta_max_rad - s.theta_min_rad) * s.design_radius_m * s.length_m / cfg.grid.cell_size_m ** 2
    s.points_per_cell = args.points / cells
    bay = _core.make_synthetic_bay(s)
    cloud = _core.estimate_normals(bay.sample(cfg.grid.cell_size_m), cfg.normals.k_neighbors, bay.axis)
    t0 = time.perf_counter()
    index = _core.SurfaceIndex(cloud)
    index_s = time.perf_counter() - t0

    model = _core.spot_model_from_config(cfg.deposition)
    # One pass along the crown, nozzle 1 m inside the wall, spraying radially outward.
    theta = math.pi / 2
    radial = np.array([0.0, math.cos(theta), math.sin(theta)])
    r_nozzle = s.design_radius_m + s.base_overbreak_m - 1.0
    poses = [_core.NozzlePose(np.array([d, 0, 0]) + r_nozzle * radial, radial) for d in (0.0, s.length_m)]
    speed, step = 0.15, 0.01
    runs = []
    thickness = None
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        thickness = _core.accumulate_pass(model, index, poses, speed, step, cfg.deposition.rebound_fraction)
        runs.append(time.perf_counter() - t0)
    touched = int(np.count_nonzero(thickness))
    # Points actually visited per sample (the query balls), against the whole cloud.
    samples = _core.resample_pass(poses, speed, step)
    visited = [len(index.within(*index.reach_ball(model, p))) for p in samples.poses]
    best_ms = min(runs) * 1e3
    result = {
        "benchmark": "deposition: one 1.2 m pass, 10 mm steps, on a synthetic bay",
        "points": len(cloud),
        "samples": len(samples.poses),
        "index_build_ms": round(index_s * 1e3, 2),
        "pass_best_ms": round(best_ms, 3),
        "pass_median_ms": round(statistics.median(runs) * 1e3, 3),
        "target_ms": 20.0,
        "meets_target": best_ms < 20.0,
        "points_with_thickness": touched,
        "mean_points_visited_per_sample": round(float(np.mean(visited)), 1),
        "peak_thickness_mm": round(float(thickness.max()) * 1e3, 3),
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "cpus": os.cpu_count(),
        "fit": {**fit_report(fit, cfg.deposition.nominal_flow_m3ph, len(data)), "fit_ms": round(fit_s * 1e3, 2)},
        "spacing_default_model_td_50mm": spacing_report(model, 0.05),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "deposition.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
