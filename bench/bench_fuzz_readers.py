"""Mutation fuzzing of every reader (tests/python/fuzz_readers.py), longer than the test suite's runs:
the cloud readers (PCD, PLY, XYZ, LAS, E57; 20,000 cases), the stroke CSV, the ordering instance
JSON and the config YAML (5,000 cases each). Writes <out>/fuzz_readers.json with, per target, the
cases run, the outcomes, and the crashes, hangs and other findings (target: none). The inputs of
findings (and notes) are kept in <out>/fuzz_readers_findings/.

    python bench/bench_fuzz_readers.py --out bench/results [--cases 20000] [--text-cases 5000] [--seed 1]
                                       [--targets clouds,stroke_csv,ordering_json,config_yaml]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "python"))
import fuzz_readers  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("bench/results"))
    ap.add_argument("--cases", type=int, default=20000, help="cases of the cloud readers")
    ap.add_argument("--text-cases", type=int, default=5000, help="cases of each text target")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--targets", default=",".join(fuzz_readers.TARGETS),
                    help=f"comma-separated, of {', '.join(fuzz_readers.TARGETS)}")
    args = ap.parse_args()
    targets = [t.strip() for t in args.targets.split(",") if t.strip()]
    unknown = [t for t in targets if t not in fuzz_readers.TARGETS]
    if unknown or not targets:
        ap.error(f"--targets: unknown {', '.join(unknown) or '(none given)'}; choose from {', '.join(fuzz_readers.TARGETS)}")
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    results = {}
    for target in targets:
        n_cases = args.cases if target == "clouds" else args.text_cases
        results[target] = fuzz_readers.run(n_cases, args.seed, keep_dir=args.out / "fuzz_readers_findings",
                                           target=target)
        r = results[target]
        print(f"fuzz_readers {target}: {r['cases']} cases in {r['seconds']:.0f} s, outcomes {r['outcomes']}, "
              f"{len(r['findings'])} findings, {r['notes']} notes", flush=True)
    n_findings = sum(len(r["findings"]) for r in results.values())
    summary = {"target": "no crash, hang or exception other than a one-line ValueError", "seed": args.seed,
               "cases": sum(r["cases"] for r in results.values()), "seconds": time.perf_counter() - t0,
               "findings": n_findings, "targets": results}
    (args.out / "fuzz_readers.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(f"fuzz_readers: {summary['cases']} cases in {summary['seconds']:.0f} s, {n_findings} findings")
    return 1 if n_findings else 0


if __name__ == "__main__":
    sys.exit(main())
