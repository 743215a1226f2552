"""Mutation fuzzing of the cloud readers (PCD, PLY, XYZ, LAS, E57), longer than the test suite's 300
cases: writes <out>/fuzz_readers.json with the cases run, the outcomes, and the crashes, hangs and
other findings (target: none). Crashing inputs are kept in <out>/fuzz_readers_findings/.

    python bench/bench_fuzz_readers.py --out bench/results [--cases 20000] [--seed 1]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "python"))
import fuzz_readers  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("bench/results"))
    ap.add_argument("--cases", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    result = fuzz_readers.run(args.cases, args.seed, keep_dir=args.out / "fuzz_readers_findings")
    result["target"] = "no crash, hang or exception other than a one-line ValueError"
    (args.out / "fuzz_readers.json").write_text(json.dumps(result, indent=1) + "\n")
    print(f"fuzz_readers: {result['cases']} cases in {result['seconds']:.0f} s, outcomes {result['outcomes']}, "
          f"{len(result['findings'])} findings")
    return 1 if result["findings"] else 0


if __name__ == "__main__":
    sys.exit(main())
