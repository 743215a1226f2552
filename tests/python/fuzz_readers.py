"""Mutation fuzzer for every reader: the cloud readers (PCD, PLY, XYZ, LAS, E57), the stroke CSV
(``shotcrete deposition fit``), the ordering instance JSON (``shotcrete order``) and the config
YAML (``--config``). Valid seed files are mutated; every case must either succeed or raise
ValueError with one non-empty line; anything else (another exception, a signal, a case slower than
the time limit) is a finding.

Clouds (seeds written by the independent writers of cloud_files.py, laspy and pye57) get bit
flips, byte changes, chunk insertions, deletions and duplications, truncation, and header numbers
replaced by hostile ones (negative, huge, zero). The text targets get the same byte mutations plus
numbers anywhere replaced by hostile ones and hostile tokens (NaN/inf spellings, overflowing
numbers, YAML tags, anchors and aliases, deep nesting, very long lines, BOM, NUL, non-UTF-8 bytes)
inserted at random bytes or where a value or a line starts.

The cases run in a child process so a crash is caught and the run goes on after it:

    python tests/python/fuzz_readers.py [--target clouds|stroke_csv|ordering_json|config_yaml]
                                        [--cases 300] [--seed 1] [--keep DIR]

Used by tests/python/test_fuzz.py (a short fixed run per target) and bench/bench_fuzz_readers.py
(a longer one).
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from functools import lru_cache
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cloud_files import pcd_bytes, ply_bytes, points  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
HOSTILE_NUMBERS = [b"-1", b"-5", b"0", b"4000000000", b"18446744073709551615", b"99999999999999999999",
                   b"2147483648", b"1e9", b"nan", b"007"]
# Text files: numbers and values as YAML, JSON and strtod might read them, and what they must refuse.
HOSTILE_VALUES = HOSTILE_NUMBERS + [
    b".nan", b".NaN", b".inf", b"-.inf", b"NaN", b"Infinity", b"-Infinity", b"inf", b"1e309", b"-1e400",
    b"1e-400", b"4.9e-324", b"9" * 400, b"-" + b"9" * 400 + b".5", b"0x1F", b"0o17", b"1_000", b"+5", b"5.",
    b"-0", b"1e", b"--1", b"1.2.3", b'"3"', b"'3'", b"null", b"~", b"true", b"yes", b'"yes"', b"[]", b"{}",
    b"[1, 2]", b'""']
HOSTILE_TOKENS = HOSTILE_VALUES + [
    b"&a", b"*a", b"&a [1, 2, 3]", b"*undefined", b"<<: *a", b"!!python/object:os.system", b"!!binary",
    b"!!str", b"!!float", b"!!int 3", b"!custom", b": :", b"? ", b"- ", b"---", b"...", b"%YAML 1.1\n---\n",
    b"%TAG ! tag:x,2000:\n", b"#", b"'", b'"', b"\\", b"\\u0000", b'"\\ud800"', b",", b":", b"\t", b"\t\t  ",
    b"\n", b"\r", b"\r\n", b"\xef\xbb\xbf", b"\x00", b"\xff", b"\xe9", b"\xc3", b"\xed\xa0\x80", b"\xf4\x90\x80\x80",
    b"\x1b[31m", b"\xe2\x80\xa8", b'{"a": 1}', b'"regions"', b'"start"', b'"a"', b'"b"']
CASE_TIME_LIMIT_S = 10.0


def cloud_seeds() -> dict[str, bytes]:
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


def stroke_seeds() -> dict[str, bytes]:
    """The measured stroke, and the same stroke as the reader's other spellings: no header, CRLF,
    spaces around the cells, exponents."""
    original = (ROOT / "data" / "deposition_stroke.csv").read_bytes()
    rows = [line.split(",") for line in original.decode().split()[1:]]
    variant = "".join(f" {float(x):.3e} ,{float(t) + 0.25} \r\n" for x, t in rows)
    return {"stroke.csv": original, "variant.csv": variant.encode()}


def ordering_seeds() -> dict[str, bytes]:
    """Two instances small enough for the exact solver of the default method (best): 10 regions on
    one line with a start point, 12 indented without one."""
    rng = np.random.default_rng(6)
    a = rng.uniform(-5.0, 5.0, (12, 3))
    b = a + rng.uniform(-1.0, 1.0, (12, 3))
    regions = [{"a": [round(float(v), 3) for v in pa], "b": [round(float(v), 3) for v in pb]} for pa, pb in zip(a, b)]
    return {"compact.json": json.dumps({"regions": regions[:10], "start": [0.0, -0.5, 1e-3]}).encode(),
            "indented.json": json.dumps({"regions": regions}, indent=1).encode()}


# A user's partial config: flow and block style, an anchor and its alias, booleans, a list, an enum.
PARTIAL_CONFIG = b"""# tiny bay, nearest-neighbour ordering
synth: {seed: 3, pit_count: 4, length_m: 0.6, theta_min_rad: 1.0, theta_max_rad: 1.4}
profile:
  estimate_axis: true
  axis_origin_m: &origin [0, 0, 0]
preprocess:
  crop_enabled: false
  crop_min_m: [-10, -10, -10]
  voxel_size_m: 0.02
ordering: {method: nn, local_search: false, seed: 7}
robot:
  base_position_m: [0.6, 0, -1.2]
"""


def config_seeds() -> dict[str, bytes]:
    """The shipped default config (every key) and a user's partial one."""
    return {"default.yaml": (ROOT / "config" / "default.yaml").read_bytes(), "partial.yaml": PARTIAL_CONFIG}


def _byte_mutation(b: bytearray, rng: np.random.Generator) -> None:
    """One random byte-level mutation of ``b``, in place."""
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


def mutate(data: bytes, rng: np.random.Generator) -> bytes:
    """One to three random byte-level mutations of ``data`` (binary and text files alike)."""
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 4))):
        _byte_mutation(b, rng)
    return bytes(b)


TEXT_NUMBER = re.compile(rb"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")
VALUE_STARTS = re.compile(rb"(^|\n|: |:|,|\[|\{)")


def _pick(rng: np.random.Generator, items: list):
    return items[int(rng.integers(0, len(items)))]


def _laughs(levels: int) -> bytes:
    """YAML aliases nested ``levels`` deep, ten per level ("billion laughs"): 10**levels leaves."""
    lines = [b"l0: &l0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [b"l%d: &l%d [" % (i, i) + b", ".join([b"*l%d" % (i - 1)] * 10) + b"]" for i in range(1, levels)]
    return b"\n".join(lines) + b"\n"


def _bulky_token(rng: np.random.Generator) -> bytes:
    """Deep nesting (up to 10,000 levels, closed or not), nested aliases, or a very long line."""
    depth = int(_pick(rng, [64, 1000, 10000]))
    kind = int(rng.integers(0, 8))
    if kind == 7:
        return _laughs(int(rng.integers(3, 10)))
    if kind == 0:
        return b"[" * depth
    if kind == 1:
        return b"[" * depth + b"1" + b"]" * depth
    if kind == 2:
        return b"{" * depth
    if kind == 3:
        return b'{"a": ' * depth + b"1" + b"}" * depth
    if kind == 4:  # YAML block sequences nested on one line, and nested flow mappings
        return _pick(rng, [b"- " * depth + b"1", b"{a: " * depth + b"1" + b"}" * depth])
    if kind == 5:  # a long number, or a long list of them
        return _pick(rng, [b"9" * 100_000, b"0." + b"0" * 5000 + b"1", b"1," * 50_000 + b"1"])
    return _pick(rng, [b"x" * 200_000, b"#" + b"c" * 200_000, b'"' + b"s" * 200_000 + b'"'])


def mutate_text(data: bytes, rng: np.random.Generator) -> bytes:
    """One to three mutations of a text file: byte-level ones, a number anywhere replaced by a
    hostile value, a hostile token inserted at a random byte or where a value or line starts, a
    line dropped or repeated, deep nesting or a very long line, a BOM."""
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 4))):
        kind = int(rng.integers(0, 8))
        if kind == 0:
            _byte_mutation(b, rng)
        elif kind == 1:  # a number anywhere in the file
            numbers = [m.span() for m in TEXT_NUMBER.finditer(bytes(b))]
            if numbers:
                s, e = _pick(rng, numbers)
                b[s:e] = _pick(rng, HOSTILE_VALUES)
        elif kind == 2:  # a token at a random byte
            pos = int(rng.integers(0, len(b) + 1))
            b[pos:pos] = _pick(rng, HOSTILE_TOKENS)
        elif kind in (3, 4):  # a token where a value, key or line starts, or a value replaced
            starts = [m.end() for m in VALUE_STARTS.finditer(bytes(b))] or [0]
            pos = _pick(rng, starts)
            token = _pick(rng, HOSTILE_TOKENS) if kind == 3 else _bulky_token(rng)
            cut = int(rng.integers(0, 2)) * len(re.match(rb"[^,\]}\n]*", bytes(b[pos:])).group())
            b[pos:pos + cut] = token
        elif kind == 5:  # a line dropped, repeated or moved
            lines = bytes(b).split(b"\n")
            i, j = int(rng.integers(0, len(lines))), int(rng.integers(0, len(lines)))
            op = int(rng.integers(0, 3))
            if op == 0:
                del lines[i]
            elif op == 1:
                lines.insert(j, lines[i])
            else:
                lines.insert(j, lines.pop(i))
            b = bytearray(b"\n".join(lines))
        elif kind == 6:  # a line's indentation changed (YAML structure; JSON and CSV whitespace)
            lines = bytes(b).split(b"\n")
            i = int(rng.integers(0, len(lines)))
            lines[i] = _pick(rng, [b"", b" ", b"  ", b"\t", b"      "]) + lines[i].lstrip()
            b = bytearray(b"\n".join(lines))
        else:  # a prefix: BOM, NUL, a non-UTF-8 byte, a YAML document marker
            b[0:0] = _pick(rng, [b"\xef\xbb\xbf", b"\x00", b"\xff\xfe", b"\xe9", b"---\n", b"--- !!map\n"])
    return bytes(b)


# ---- the action per target: what the CLI does with the file ----------------------------------------

@lru_cache(maxsize=1)
def _defaults():
    import shotcrete

    return shotcrete.load_config()


def read_cloud_case(path: Path, notes: list[str]) -> str:
    import shotcrete

    return f"{len(shotcrete.read_cloud(path))} points"


class CoreMessageBroken(Exception):
    """The core called alone (as the ROS node and the Python API do) refused with a message that
    is empty or not one printable line: a finding since the core quotes input printably."""


def _core_alone(call) -> None:
    try:
        call()
    except ValueError as exc:
        if not _one_line(str(exc)) or "\r" in str(exc):
            raise CoreMessageBroken(f"core alone: {str(exc)!r}") from None


def fit_stroke_case(path: Path, notes: list[str]) -> str:
    """``shotcrete deposition fit CSV`` with its defaults (1000 mm standoff, 150 mm/s, the
    config's rebound), and the core's reader alone."""
    from shotcrete import _core
    from shotcrete.deposition import fit_report, read_stroke_csv

    cfg = _defaults().deposition
    _core_alone(lambda: _core.read_stroke_csv(str(path), 1.0, 0.15, cfg.rebound_fraction))
    data = read_stroke_csv(path, 1000.0 * 1e-3, 150.0 * 1e-3, cfg.rebound_fraction)
    report = fit_report(_core.fit_stroke(data), cfg.nominal_flow_m3ph, len(data))
    json.dumps(report, allow_nan=False)  # --json
    return f"{len(data)} rows, R {report['radius_mm']:.1f} mm"


def solve_order_case(path: Path, notes: list[str]) -> str:
    """``shotcrete order INSTANCE.json --json`` with the default config (method best)."""
    from shotcrete import _core
    from shotcrete.ordering import load_instance, result_json

    problem = load_instance(path)
    result = _core.solve_ordering(problem, _defaults().ordering)
    json.dumps(result_json(result, len(problem)), allow_nan=False)
    return f"{len(problem)} regions, {result.method}"


def load_config_case(path: Path, notes: list[str]) -> str:
    """``--config FILE`` (shotcrete.load_config: the strict check, then the core) and the core's
    loader alone (as the ROS node reads it): both must load or refuse with a one-line ValueError."""
    import shotcrete
    from shotcrete._core import Config

    _core_alone(lambda: Config.load(str(path)))
    shotcrete.load_config(path)
    return "loads"


class Target(NamedTuple):
    seeds: Callable[[], dict[str, bytes]]
    mutate: Callable[[bytes, np.random.Generator], bytes]
    # (path, notes) -> a short description, or ValueError to refuse; notes: defects that are no finding
    action: Callable[[Path, list], str]


TARGETS = {
    "clouds": Target(cloud_seeds, mutate, read_cloud_case),
    "stroke_csv": Target(stroke_seeds, mutate_text, fit_stroke_case),
    "ordering_json": Target(ordering_seeds, mutate_text, solve_order_case),
    "config_yaml": Target(config_seeds, mutate_text, load_config_case),
}


def _one_line(msg: str) -> bool:
    """The CLI prints a refusal as one line: non-empty, no line break a terminal would honour."""
    return bool(msg.strip()) and "\n" not in msg and "\r" not in msg


def child(workdir: Path, target: str, cases: list[tuple[int, str, bytes]]) -> None:
    """Runs each case, printing one JSON line before (start) and after (outcome) it."""
    import signal

    action = TARGETS[target].action
    signal.signal(signal.SIGALRM, signal.SIG_DFL)  # a case past the limit ends the child: a "hang"
    for index, name, data in cases:
        path = workdir / f"case{index}_{name}"
        path.write_bytes(data)
        print(json.dumps({"start": index}), flush=True)
        t0 = time.perf_counter()
        notes: list[str] = []
        signal.alarm(int(CASE_TIME_LIMIT_S))
        try:
            outcome, detail = "read", action(path, notes)
        except ValueError as exc:
            msg = str(exc)
            outcome, detail = ("refused", msg) if _one_line(msg) else ("bad_message", repr(msg))
        except BaseException as exc:  # noqa: BLE001 - anything but ValueError is a finding
            outcome, detail = "other_exception", f"{type(exc).__name__}: {exc}"
        signal.alarm(0)
        print(json.dumps({"case": index, "outcome": outcome, "detail": detail[:300], "notes": [n[:300] for n in notes],
                          "seconds": time.perf_counter() - t0}), flush=True)
        path.unlink()


def run(n_cases: int, seed: int = 1, keep_dir: Path | None = None, target: str = "clouds") -> dict:
    """Runs ``n_cases`` mutated files of ``target`` through its action; returns the tally and the
    findings (a finding's input is written to ``keep_dir`` if given)."""
    rng = np.random.default_rng(seed)
    spec = TARGETS[target]
    seed_files = spec.seeds()
    names = sorted(seed_files)
    cases = []
    for i in range(n_cases):
        name = names[i % len(names)]
        cases.append((i, name, spec.mutate(seed_files[name], rng)))
    by_index = {c[0]: c for c in cases}
    tally: dict[str, int] = {}
    findings, notes = [], []

    def keep(kind: str, index: int) -> None:
        if keep_dir is not None:
            keep_dir.mkdir(parents=True, exist_ok=True)
            _, name, data = by_index[index]
            (keep_dir / f"{target}_{kind}{index}_{name}").write_bytes(data)

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        todo = cases
        while todo:
            started, done = None, set()
            proc = subprocess.Popen([sys.executable, __file__, "--child", str(workdir), "--target", target],
                                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                    text=True)
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
                if rec["notes"]:
                    notes += [{"case": rec["case"], "file": by_index[rec["case"]][1], "note": n} for n in rec["notes"]]
                    keep("note", rec["case"])
                outcome = rec["outcome"]
                if outcome in ("read", "refused") and rec["seconds"] > CASE_TIME_LIMIT_S:
                    outcome = "slow"
                tally[outcome] = tally.get(outcome, 0) + 1
                if outcome not in ("read", "refused"):
                    findings.append({"case": rec["case"], "outcome": outcome, "detail": rec["detail"],
                                     "file": by_index[rec["case"]][1]})
                    keep(outcome, rec["case"])
            if proc.returncode != 0 and started is not None and started not in done:
                kind = "hang" if proc.returncode == -14 else "crash"  # -14: SIGALRM, the case time limit
                tally[kind] = tally.get(kind, 0) + 1
                findings.append({"case": started, "outcome": kind, "detail": f"exit {proc.returncode}",
                                 "file": by_index[started][1]})
                keep(kind, started)
                done.add(started)
            elif proc.returncode != 0:
                raise RuntimeError(f"fuzz child failed before any case (exit {proc.returncode})")
            todo = [c for c in todo if c[0] not in done]
    return {"target": target, "cases": n_cases, "seed": seed, "seconds": time.perf_counter() - t0,
            "outcomes": tally, "crashes": tally.get("crash", 0), "hangs": tally.get("hang", 0),
            "findings": findings, "notes": len(notes), "note_examples": notes[:20]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--target", choices=sorted(TARGETS), default="clouds")
    ap.add_argument("--cases", type=int, default=300)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keep", type=Path, default=None, help="directory for the inputs of findings")
    ap.add_argument("--child", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        child(args.child, args.target, [(i, n, bytes.fromhex(d)) for i, n, d in json.loads(sys.stdin.read())])
        return 0
    result = run(args.cases, args.seed, args.keep, args.target)
    print(json.dumps(result, indent=1))
    return 1 if result["findings"] else 0


if __name__ == "__main__":
    sys.exit(main())
