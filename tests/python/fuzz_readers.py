"""Mutation fuzzer for the cloud readers (PCD, PLY, XYZ, LAS, E57): valid seed files (written by
the independent writers of cloud_files.py, laspy and pye57) mutated by bit flips, byte changes, chunk
insertions, deletions and duplications, truncation, and header numbers replaced by hostile ones
(negative, huge, zero). Every case must either read or raise ValueError with one line; anything
else (another exception, a signal, a case slower than the time limit) is a finding.

The cases run in a child process so a crash is caught and the run goes on after it:

    python tests/python/fuzz_readers.py --cases 300 --seed 1 [--json]

Used by tests/python/test_fuzz.py (a short fixed run) and bench/run_benchmarks.py (a longer one).
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cloud_files import pcd_bytes, ply_bytes, points  # noqa: E402

HOSTILE_NUMBERS = [b"-1", b"-5", b"0", b"4000000000", b"18446744073709551615", b"99999999999999999999",
                   b"2147483648", b"1e9", b"nan", b"007"]
CASE_TIME_LIMIT_S = 10.0


def seeds() -> dict[str, bytes]:
    """Valid files, one per reader and layout: name (with the extension that picks the reader) -> bytes."""
    arr = points(40, "f8", extras=True, normals=True, order="interleaved", seed=1)
    arr32 = points(40, "f4", extras=True, seed=2)
    out = {
        "ascii.pcd": pcd_bytes(arr32, "ascii"),
        "binary.pcd": pcd_bytes(arr, "binary"),
        "compressed.pcd": pcd_bytes(arr32, "binary_compressed"),
        "ascii.ply": ply_bytes(arr32, "ascii", faces=2),
        "binary.ply": ply_bytes(arr, "binary_little_endian"),
        "big.ply": ply_bytes(arr32, "binary_big_endian", faces=2),
        "cloud.xyz": "\n".join(" ".join(f"{v:.6f}" for v in row) for row in np.random.default_rng(3).normal(size=(40, 6)))
        .encode(),
    }
    try:
        import laspy

        header = laspy.LasHeader(point_format=3, version="1.2")
        header.scales = np.array([1e-4, 1e-4, 1e-4])
        las = laspy.LasData(header)
        xyz = np.random.default_rng(4).normal(size=(40, 3))
        las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        with tempfile.TemporaryDirectory() as tmp:
            las.write(str(Path(tmp) / "s.las"))
            out["cloud.las"] = (Path(tmp) / "s.las").read_bytes()
    except ImportError:  # pragma: no cover
        pass
    try:
        import pye57

        xyz = np.random.default_rng(5).normal(size=(40, 3))
        with tempfile.TemporaryDirectory() as tmp:
            e57 = pye57.E57(str(Path(tmp) / "s.e57"), mode="w")
            e57.write_scan_raw({"cartesianX": xyz[:, 0], "cartesianY": xyz[:, 1], "cartesianZ": xyz[:, 2]})
            e57.close()
            out["scan.e57"] = (Path(tmp) / "s.e57").read_bytes()
    except ImportError:  # pragma: no cover
        pass
    return out


def mutate(data: bytes, rng: np.random.Generator) -> bytes:
    """One to three random mutations of ``data``."""
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 4))):
        kind = int(rng.integers(0, 7))
        pos = int(rng.integers(0, max(1, len(b))))
        if kind == 0 and b:  # bit flip
            b[pos % len(b)] ^= 1 << int(rng.integers(0, 8))
        elif kind == 1 and b:  # random byte
            b[pos % len(b)] = int(rng.integers(0, 256))
        elif kind == 2:  # insert random bytes
            b[pos:pos] = rng.integers(0, 256, int(rng.integers(1, 64)), dtype=np.uint8).tobytes()
        elif kind == 3:  # delete a chunk
            del b[pos:pos + int(rng.integers(1, 128))]
        elif kind == 4:  # duplicate a chunk
            b[pos:pos] = b[pos:pos + int(rng.integers(1, 256))]
        elif kind == 5:  # truncate
            del b[pos:]
        else:  # a number in the header replaced by a hostile one
            head = bytes(b[:600])
            numbers = [m.span() for m in re.finditer(rb"-?\d+", head)]
            if numbers:
                s, e = numbers[int(rng.integers(0, len(numbers)))]
                b[s:e] = HOSTILE_NUMBERS[int(rng.integers(0, len(HOSTILE_NUMBERS)))]
    return bytes(b)


def child(workdir: Path, cases: list[tuple[int, str, bytes]]) -> None:
    """Reads each case, printing one JSON line before (start) and after (outcome) it."""
    import signal

    import shotcrete

    signal.signal(signal.SIGALRM, signal.SIG_DFL)  # a case past the limit ends the child: a "hang"
    for index, name, data in cases:
        path = workdir / f"case{index}_{name}"
        path.write_bytes(data)
        print(json.dumps({"start": index}), flush=True)
        t0 = time.perf_counter()
        signal.alarm(int(CASE_TIME_LIMIT_S))
        try:
            cloud = shotcrete.read_cloud(path)
            outcome, detail = "read", f"{len(cloud)} points"
        except ValueError as exc:
            msg = str(exc)
            outcome, detail = ("refused", msg) if msg and "\n" not in msg else ("bad_message", msg)
        except BaseException as exc:  # noqa: BLE001 - anything but ValueError is a finding
            outcome, detail = "other_exception", f"{type(exc).__name__}: {exc}"
        signal.alarm(0)
        print(json.dumps({"case": index, "outcome": outcome, "detail": detail[:300],
                          "seconds": time.perf_counter() - t0}), flush=True)
        path.unlink()


def run(n_cases: int, seed: int = 1, keep_dir: Path | None = None) -> dict:
    """Runs ``n_cases`` mutated files through the readers; returns the tally and the findings."""
    rng = np.random.default_rng(seed)
    seed_files = seeds()
    names = sorted(seed_files)
    cases = []
    for i in range(n_cases):
        name = names[i % len(names)]
        cases.append((i, name, mutate(seed_files[name], rng)))
    tally: dict[str, int] = {}
    findings = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        todo = cases
        while todo:
            started, done = None, set()
            proc = subprocess.Popen([sys.executable, __file__, "--child", str(workdir)], stdin=subprocess.PIPE,
                                    stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            payload = json.dumps([(i, n, d.hex()) for i, n, d in todo])
            try:
                out, _ = proc.communicate(payload, timeout=CASE_TIME_LIMIT_S * len(todo) + 60)
            except subprocess.TimeoutExpired:
                proc.kill()
                out, _ = proc.communicate()
            for line in out.splitlines():
                rec = json.loads(line)
                if "start" in rec:
                    started = rec["start"]
                    continue
                done.add(rec["case"])
                outcome = rec["outcome"]
                if outcome == "read" and rec["seconds"] > CASE_TIME_LIMIT_S:
                    outcome = "slow"
                tally[outcome] = tally.get(outcome, 0) + 1
                if outcome not in ("read", "refused"):
                    findings.append({"case": rec["case"], "outcome": outcome, "detail": rec["detail"]})
            if proc.returncode != 0 and started is not None and started not in done:
                kind = "hang" if proc.returncode == -14 else "crash"  # -14: SIGALRM, the case time limit
                tally[kind] = tally.get(kind, 0) + 1
                crashed = next(c for c in todo if c[0] == started)
                finding = {"case": started, "outcome": kind, "detail": f"exit {proc.returncode}", "file": crashed[1]}
                if keep_dir is not None:
                    keep_dir.mkdir(parents=True, exist_ok=True)
                    (keep_dir / f"{kind}{started}_{crashed[1]}").write_bytes(crashed[2])
                findings.append(finding)
                done.add(started)
            elif proc.returncode != 0:
                raise RuntimeError(f"fuzz child failed before any case (exit {proc.returncode})")
            todo = [c for c in todo if c[0] not in done]
    return {"cases": n_cases, "seed": seed, "seconds": time.perf_counter() - t0, "outcomes": tally,
            "crashes": tally.get("crash", 0), "hangs": tally.get("hang", 0), "findings": findings}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=300)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keep", type=Path, default=None, help="directory for crashing inputs")
    ap.add_argument("--child", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        child(args.child, [(i, n, bytes.fromhex(d)) for i, n, d in json.loads(sys.stdin.read())])
        return 0
    result = run(args.cases, args.seed, args.keep)
    print(json.dumps(result, indent=1))
    return 1 if result["findings"] else 0


if __name__ == "__main__":
    sys.exit(main())
