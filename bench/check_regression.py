"""Runs the default demo in both planner modes and compares every number of report.json with the
figures recorded in bench/reference/demo_report_numbers.json (relative tolerance 1e-6; wall-clock
timings excluded). A refactoring that changes a result fails here.

    .venv/bin/python bench/check_regression.py            # compare (exit 1 on any difference)
    .venv/bin/python bench/check_regression.py --record   # write the reference anew (the modes run)
"""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "bench" / "reference" / "demo_report_numbers.json"
MODES = ("optimal", "graded")
# Wall-clock figures and file names: not results.
SKIP = {"timings_s", "report_html", "files", "provenance"}


def flatten(node, prefix: str = "") -> dict:
    """Leaves of a JSON tree by dotted path ('rounds_detail.2.spray_time_s')."""
    out = {}
    if isinstance(node, dict):
        for k, v in node.items():
            if k not in SKIP:
                out.update(flatten(v, f"{prefix}{k}."))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out.update(flatten(v, f"{prefix}{i}."))
    else:
        out[prefix[:-1]] = node
    return out


def run_demo(mode: str, workdir: Path) -> dict:
    config = yaml.safe_load((ROOT / "config" / "default.yaml").read_text())
    config["planner"]["mode"] = mode
    cfg_path = workdir / f"{mode}.yaml"
    cfg_path.write_text(yaml.safe_dump(config))
    exe = Path(sys.executable).parent / "shotcrete"
    proc = subprocess.run([str(exe), "demo", "--json", "--config", str(cfg_path), "--out", str(workdir / mode)],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"demo ({mode}) failed with exit {proc.returncode}:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout)


def compare(ref: dict, got: dict, rel: float) -> list[str]:
    problems = []
    for key, want in ref.items():
        if key not in got:
            problems.append(f"{key}: missing (reference {want!r})")
            continue
        have = got[key]
        if isinstance(want, (int, float)) and not isinstance(want, bool) and isinstance(have, (int, float)):
            if not math.isclose(float(want), float(have), rel_tol=rel, abs_tol=1e-12):
                problems.append(f"{key}: {have!r} (reference {want!r})")
        elif want != have:
            problems.append(f"{key}: {have!r} (reference {want!r})")
    return problems


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--record", action="store_true", help="write the reference from this build")
    ap.add_argument("--rel", type=float, default=1e-6, help="relative tolerance")
    ap.add_argument("--modes", nargs="*", default=list(MODES), choices=MODES)
    args = ap.parse_args()
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for mode in args.modes:
            print(f"[regression] demo, planner.mode = {mode} ...", flush=True)
            results[mode] = flatten(run_demo(mode, Path(tmp)))
    if args.record:
        # Only the modes run are replaced: `--record --modes optimal` keeps graded's figures.
        recorded = json.loads(REFERENCE.read_text()) if REFERENCE.is_file() else {}
        recorded.update(results)
        REFERENCE.parent.mkdir(parents=True, exist_ok=True)
        REFERENCE.write_text(json.dumps(recorded, indent=1, sort_keys=True) + "\n")
        print(f"[regression] recorded {sum(len(v) for v in results.values())} numbers to {REFERENCE}")
        return 0
    reference = json.loads(REFERENCE.read_text())
    failed = False
    for mode in args.modes:
        problems = compare(reference[mode], results[mode], args.rel)
        print(f"[regression] {mode}: {len(reference[mode])} figures, {len(problems)} differ")
        for p in problems[:40]:
            print(f"    {p}")
        failed = failed or bool(problems)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
