"""Job outputs and CLI robustness (issue 17; docs/architecture.md §10): atomic output sets with a
backup, report.json's provenance, the lock per output directory, one-line errors with exit 2,
single-file outputs never overwritten without --force, a strict config reader."""
import errno
import hashlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import shotcrete
from shape_distance import shape_distance
from shotcrete import pipeline

SHOTCRETE = str(Path(sys.executable).parent / "shotcrete")
ROOT = Path(__file__).resolve().parents[2]
# A small bay: a few seconds a job, figures and a trajectory like the default's.
TINY_BAY = "synth: {theta_min_rad: 1.0, theta_max_rad: 1.4, length_m: 0.6, points_per_cell: 6, pit_count: 2}\n"
# The same bay with the arm's base 6 m below its place: the wall is out of reach, no trajectory.
NO_REACH = TINY_BAY + "robot: {base_position_m: [0.6, 0, -7.2]}\n"


def _cli(*args, env=None, **kw):
    return subprocess.run([SHOTCRETE, *map(str, args)], capture_output=True, text=True, env=env, **kw)


def _snapshot(out: Path) -> dict:
    """Every file under ``out`` with its sha256."""
    return {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(out.rglob("*")) if p.is_file()}


def _leftovers(out: Path) -> list:
    """Temporary directories, old backups being removed, or the lock of jobs on ``out``."""
    return sorted(p.name for p in out.parent.iterdir()
                  if p.name.startswith((f".{out.name}.tmp-", f".{out.name}.old-", f".{out.name}.lock")))


def _assert_complete(out: Path) -> None:
    """Every file report.json and report.html name is there, and nothing else."""
    report = json.loads((out / "report.json").read_text())
    html = (out / "report.html").read_text()
    named = set(report["files"].values()) | {s.split('"')[0] for s in html.split('src="')[1:]}
    assert set(_snapshot(out)) == named | {"report.json", "report.html", ".shotcrete-output"}


def _one_error_line(stderr: str) -> str:
    """The one error line of ``stderr``; the others may only be warnings and the progress display
    (stage, bar, elapsed time)."""
    lines = [ln for ln in stderr.splitlines() if ln.strip() and not ln.startswith("warning:")
             and not re.fullmatch(r"[a-z0-9 ]+ [━ ]* ?\d+:\d\d:\d\d", ln)]
    assert len(lines) == 1 and lines[0].startswith("error: "), stderr
    assert "Traceback" not in stderr
    return lines[0]


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    """A complete demo set in <dir>/demo (copied per test), and its snapshot."""
    base = tmp_path_factory.mktemp("first")
    cfg = base / "tiny.yaml"
    cfg.write_text(TINY_BAY)
    r = _cli("demo", "--out", base / "demo", "--config", cfg, "--json")
    assert r.returncode == 0, r.stderr
    return base / "demo", cfg


@pytest.fixture()
def previous(first_run, tmp_path):
    """A copy of a complete earlier run in tmp_path/demo; returns (out, its snapshot, config)."""
    import shutil

    src, cfg = first_run
    out = tmp_path / "demo"
    shutil.copytree(src, out)
    snap = _snapshot(out)
    assert {"report.json", "report.html", "plan.json", "trajectory.npz", "surface.ply", "sprayed.ply",
            ".shotcrete-output"} <= set(snap)
    return out, snap, cfg


def test_failed_rerun_keeps_the_previous_set(previous, run_cli, monkeypatch):
    """Disk full while the trajectory is written (after the figures and plan.json): one line,
    exit 2, the previous set untouched, nothing left beside it."""
    out, snap, cfg = previous

    def disk_full(path, **arrays):
        Path(path).write_bytes(b"\0" * 100)  # what a full disk leaves: a truncated file
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(pipeline, "_save_npz", disk_full)
    r = run_cli("demo", "--out", out, "--config", cfg)
    assert r.exit_code == 2
    line = _one_error_line(r.output)
    assert "No space left on device" in line and "trajectory.npz" in line
    assert _snapshot(out) == snap
    assert _leftovers(out) == [] and not out.with_name("demo.prev").exists()


def test_rerun_without_trajectory_leaves_no_stale_file(previous):
    """A re-run whose IK fails writes a complete set without trajectory.npz; the previous set,
    trajectory included, is kept whole in demo.prev."""
    out, snap, _ = previous
    cfg = out.parent / "noreach.yaml"
    cfg.write_text(NO_REACH)
    r = _cli("demo", "--out", out, "--config", cfg, "--json")
    assert r.returncode == 3, r.stderr  # planned, not executable: the set is written, no success
    report = json.loads((out / "report.json").read_text())
    assert report["ik"]["solved"] is False and "trajectory" not in report["files"]
    assert report["status"] == "not_executable" and "arm_cannot_follow" in [p["code"] for p in report["problems"]]
    assert not (out / "trajectory.npz").exists()
    assert {f for f in _snapshot(out) if not f.startswith("figures/")} == {
        ".shotcrete-output", "report.json", "report.html", "plotly.min.js", "cells.csv", "plan.json", "surface.ply",
        "sprayed.ply"}
    assert _snapshot(out.with_name("demo.prev")) == snap
    assert _leftovers(out) == []
    _assert_complete(out)


def _wait_for(predicate, proc, what, limit_s=120.0):
    t0 = time.monotonic()
    while not predicate():
        assert proc.poll() is None, f"the job ended before {what}: {proc.stderr.read()}"
        assert time.monotonic() - t0 < limit_s, f"no {what}"
        time.sleep(0.01)


def test_kill_9_mid_write_keeps_the_previous_set_and_the_next_job_recovers(previous):
    out, snap, cfg = previous
    seed2 = out.parent / "seed2.yaml"
    seed2.write_text(TINY_BAY.replace("pit_count: 2}", "pit_count: 2, seed: 2}"))
    proc = subprocess.Popen([SHOTCRETE, "demo", "--out", str(out), "--config", str(seed2)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    figures = lambda: [p for p in out.parent.glob(".demo.tmp-*/figures/*.png")]  # noqa: E731
    _wait_for(figures, proc, "figure in the temporary directory")
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL
    assert _snapshot(out) == snap
    # The next job takes the stale lock over, removes the killed job's files and replaces the set.
    r = _cli("demo", "--out", out, "--config", seed2)
    assert r.returncode == 0, r.stderr
    assert f"stale lock of {out.resolve()} (pid {proc.pid} on host {socket.gethostname()}" in r.stderr
    assert "unfinished output of an earlier job" in r.stderr
    assert _leftovers(out) == []
    assert _snapshot(out.with_name("demo.prev")) == snap
    assert _snapshot(out)["report.json"] != snap["report.json"]
    _assert_complete(out)
    _assert_complete(out.with_name("demo.prev"))


def test_second_job_on_the_same_out_fails_at_once_naming_the_holder(tmp_path):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY_BAY)
    out = tmp_path / "job"
    lock = tmp_path / ".job.lock"
    first = subprocess.Popen([SHOTCRETE, "demo", "--out", str(out), "--config", str(cfg)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    _wait_for(lambda: lock.exists() and lock.read_text().strip(), first, "lock file")
    second = _cli("demo", "--out", out, "--config", cfg)
    still_running = first.poll() is None
    assert second.returncode == 2
    line = _one_error_line(second.stderr)
    assert f"is in use by another shotcrete job (pid {first.pid} on host {socket.gethostname()}, started 20" in line
    assert str(lock) in line
    first.wait()
    assert still_running and first.returncode == 0, first.stderr.read()
    assert "stale" not in second.stderr
    assert (out / "report.json").is_file() and _leftovers(out) == []


def test_report_records_the_inputs_hashes_and_version(tmp_path, run_cli):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY_BAY)
    cloud = tmp_path / "bay.xyz"
    assert run_cli("synth", "--out", cloud, "--config", cfg).exit_code == 0
    r = run_cli("plan", cloud, "--out", tmp_path / "job", "--config", cfg, "--units", "m")
    assert r.exit_code == 0, r.output
    prov = json.loads((tmp_path / "job" / "report.json").read_text())["provenance"]
    sha = lambda p: hashlib.sha256(Path(p).read_bytes()).hexdigest()  # noqa: E731
    assert prov["version"] == shotcrete.__version__
    assert prov["inputs"]["cloud"] == {"path": str(cloud.resolve()), "sha256": sha(cloud)}
    assert prov["inputs"]["config"] == {"path": str(cfg.resolve()), "sha256": sha(cfg)}
    config = shotcrete.load_config(cfg)
    assert prov["config_effective_sha256"] == hashlib.sha256(config.to_yaml().encode()).hexdigest()
    xyz = np.ascontiguousarray(shotcrete.read_cloud(cloud).xyz, dtype=np.float64)
    assert prov["points"] == len(xyz) and prov["points_sha256"] == hashlib.sha256(xyz.tobytes()).hexdigest()


def test_demo_provenance_is_the_config_and_the_generated_bay(first_run):
    out, cfg = first_run
    prov = json.loads((out / "report.json").read_text())["provenance"]
    assert set(prov["inputs"]) == {"config"}
    assert prov["inputs"]["config"]["sha256"] == hashlib.sha256(cfg.read_bytes()).hexdigest()
    synth = shotcrete.load_config(cfg)
    assert prov["config_effective_sha256"] == hashlib.sha256(synth.to_yaml().encode()).hexdigest()
    synth.synth.seed += 1  # another generated bay: another hash
    assert prov["config_effective_sha256"] != hashlib.sha256(synth.to_yaml().encode()).hexdigest()


def test_os_errors_are_one_line_exit_2(tmp_path):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    r = _cli("demo", "--out", blocker / "sub")
    assert r.returncode == 2
    out = (blocker / "sub").resolve()
    assert _one_error_line(r.stderr) == f"error: output directory {out} lies under {blocker.resolve()}, which is not a directory"
    assert blocker.read_text() == "x"


def test_read_only_directory_is_one_line_exit_2(tmp_path):
    import tempfile

    outer = Path(tempfile.mkdtemp())  # not under tmp_path: the job may run as nobody, who needs to reach it
    ro = outer / "ro"
    try:
        outer.chmod(0o755)
        (outer / "tiny.yaml").write_text(TINY_BAY)
        ro.mkdir(mode=0o555)
        kw = {}
        if os.geteuid() == 0:  # root writes anywhere: run the job as nobody
            kw = {"user": 65534, "group": 65534, "env": {**os.environ, "MPLCONFIGDIR": str(outer / "mpl")}}
            (outer / "mpl").mkdir(mode=0o777)
            (outer / "mpl").chmod(0o777)
        r = _cli("demo", "--out", ro / "out", "--config", outer / "tiny.yaml", **kw)
        assert r.returncode == 2, r.stderr
        assert _one_error_line(r.stderr) == f"error: {ro / '.out.lock'}: Permission denied"
        assert list(ro.iterdir()) == []
    finally:
        ro.chmod(0o755)
        import shutil

        shutil.rmtree(outer)


def test_messages_keep_their_brackets(tmp_path):
    r = _cli("plan", tmp_path / "scan[x, y, z].xyz", "--out", tmp_path / "o")
    assert r.returncode == 2
    assert "scan[x, y, z].xyz" in _one_error_line(r.stderr)


def test_non_utf8_config_is_one_line_exit_2(tmp_path):
    cfg = tmp_path / "latin1.yaml"
    cfg.write_bytes("synth:\n  seed: 3  # caf\u00e9\n".encode("latin-1"))
    r = _cli("demo", "--out", tmp_path / "o", "--config", cfg)
    assert r.returncode == 2
    assert _one_error_line(r.stderr) == f"error: {cfg} line 2: not UTF-8 text (byte 0xe9)"
    assert not (tmp_path / "o").exists()


CSV = ROOT / "data" / "deposition_stroke.csv"


@pytest.mark.parametrize("args", [
    ["deposition", "fit", CSV, "--figure"],
    ["robot", "reach", "--radius-m", 5.6, "--n-theta", 5, "--n-d", 2, "--figure"],
    ["order", "INSTANCE", "--method", "aco", "--convergence-figure"],
])
def test_single_file_outputs_need_force(tmp_path, run_cli, args):
    inst = tmp_path / "inst.json"
    inst.write_text(json.dumps({"regions": [{"a": [0, 0, 0], "b": [1, 0, 0]}, {"a": [2, 0, 0], "b": [3, 0, 0]}]}))
    args = [inst if a == "INSTANCE" else a for a in args]
    fig = tmp_path / "mine.png"
    fig.write_bytes(b"not shotcrete's")
    r = run_cli(*args, fig)
    assert r.exit_code == 2 and f"{fig} exists; pass --force to overwrite it" in r.output
    assert fig.read_bytes() == b"not shotcrete's"
    r = run_cli(*args, fig, "--force")
    assert r.exit_code == 0, r.output
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("text, message", [
    ('profile:\n  estimate_axis: "yes"\n', "line 2: config key 'profile.estimate_axis' must be true or false"),
    ("ordering:\n  seed: 1\n  local_search: on please\n",
     "line 3: config key 'ordering.local_search' must be true or false"),
    ("synth:\n  seed: 1\n  pit_count: 3\n  seed: 2\n", "line 4: duplicate key 'synth.seed' (first on line 2)"),
    ("synth: {seed: 1}\ngrid: {}\nsynth: {seed: 2}\n", "line 3: duplicate key 'synth' (first on line 1)"),
])
def test_strict_config(tmp_path, run_cli, text, message):
    cfg = tmp_path / "c.yaml"
    cfg.write_text(text)
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        shotcrete.load_config(cfg)
    r = _cli("robot", "info", "--config", cfg)
    assert r.returncode == 2 and _one_error_line(r.stderr).startswith(f"error: {cfg} {message}")


def test_strict_config_accepts_real_booleans(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("profile:\n  estimate_axis: yes\npreprocess:\n  crop_enabled: False\nordering: {local_search: true}\n")
    c = shotcrete.load_config(cfg)
    assert c.profile.estimate_axis is True and c.preprocess.crop_enabled is False and c.ordering.local_search
    shotcrete.load_config(shotcrete.default_config_path())


# ---- findings of the fuzzer's text targets (tests/python/fuzz_readers.py): each input is refused
# with one line naming the file and its line, exit 2 through the CLI --------------------------------

@pytest.mark.parametrize("row, bad_row, message", [
    # a cell of non-UTF-8 bytes: the core quotes the cell and pybind11 could not decode its message,
    # which arrived as ValueError('')
    (b"-100,24\n", b"-100,24\xc1\xb1J\n", "line 7: not UTF-8 text (byte 0xc1)"),
    # a carriage return inside a cell: the core's message carried it and overwrote itself
    (b"-20,38\n", b"-20,3\r8\n",
     "line 11: a carriage return without a line feed (only tabs and LF or CRLF line ends are allowed)"),
    (b"0,39\n", b"0,39\x00\n", "line 12: control character U+0000 (only tabs and LF or CRLF line ends are allowed)"),
])
def test_fuzz_finding_stroke_csv_that_is_not_text(tmp_path, row, bad_row, message):
    from shotcrete.deposition import read_stroke_csv

    csv = tmp_path / "stroke.csv"
    csv.write_bytes(CSV.read_bytes().replace(row, bad_row))
    with pytest.raises(ValueError) as err:
        read_stroke_csv(csv, 1.0, 0.15, 0.08)
    assert str(err.value) == f"{csv} {message}"
    r = _cli("deposition", "fit", csv)
    assert r.returncode == 2 and _one_error_line(r.stderr) == f"error: {csv} {message}"


@pytest.mark.parametrize("text, message", [
    # RecursionError in json.loads
    ('{"regions": ' + "[" * 10000, "is not valid JSON for an instance: arrays or objects nested too deeply"),
    # OverflowError in float(): a JSON integer of 400 digits
    ('{"regions": [{"a": [' + "9" * 400 + ', 0, 0], "b": [1, 0, 0]}]}', "region 0 endpoint a: 9"),
])
def test_fuzz_finding_ordering_instance(tmp_path, text, message):
    from shotcrete.ordering import load_instance

    inst = tmp_path / "inst.json"
    inst.write_text(text)
    with pytest.raises(ValueError, match=re.escape(message)) as err:
        load_instance(inst)
    assert len(str(err.value)) < 200  # the 400 digits are shortened
    r = _cli("order", inst)
    assert r.returncode == 2 and _one_error_line(r.stderr) == f"error: {err.value}"


@pytest.mark.parametrize("text, message", [
    # RecursionError in yaml.compose
    ("synth: " + "[" * 10000 + "\n", ": malformed YAML: collections nested too deeply for a config"),
    # PyYAML read the CR as a line break, yaml-cpp as part of the key: "unknown section 'p\rofile'"
    ("p\rofile:\n  estimate_axis: true\n", " line 1: a carriage return without a line feed"),
    ("synth:\n  seed: 3\x1b[31m\n", " line 2: control character U+001B"),
])
def test_fuzz_finding_config(tmp_path, text, message):
    cfg = tmp_path / "c.yaml"
    cfg.write_bytes(text.encode())
    with pytest.raises(ValueError, match=re.escape(f"{cfg}{message}")):
        shotcrete.load_config(cfg)
    r = _cli("plan", tmp_path / "scan.pcd", "--out", tmp_path / "o", "--config", cfg)
    assert r.returncode == 2 and _one_error_line(r.stderr).startswith(f"error: {cfg}{message}")
    assert not (tmp_path / "o").exists()


def test_config_with_nested_aliases_is_refused_in_time(tmp_path):
    # "billion laughs": the strict check walked every alias again, 10**9 visits (found reading the
    # check; the fuzzer's text mutations insert it since)
    lines = ["synth:", "  seed: 1", "l0: &l0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 10) + "]" for i in range(1, 9)]
    cfg = tmp_path / "laughs.yaml"
    cfg.write_text("\n".join(lines) + "\n")
    t0 = time.perf_counter()
    r = _cli("robot", "info", "--config", cfg, timeout=60)
    assert r.returncode == 2 and _one_error_line(r.stderr) == f"error: {cfg}: config: unknown section 'l0'"
    assert time.perf_counter() - t0 < 10


def test_crlf_text_inputs_are_still_read(tmp_path):
    # the text check refuses a CR alone, not the CRLF line ends of a Windows editor
    cfg = tmp_path / "crlf.yaml"
    cfg.write_bytes(b"synth:\r\n  seed: 3\r\n  pit_count: 2\r\n")
    assert shotcrete.load_config(cfg).synth.seed == 3
    csv = tmp_path / "crlf.csv"
    csv.write_bytes(CSV.read_bytes().replace(b"\n", b"\r\n"))
    r = _cli("deposition", "fit", csv, "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["rows"] == 21


# ------------------------------------------------------------------ right or refused (exit 3)

def _problems_from_report(report: dict) -> set:
    """The problem codes a plan's report.json implies, re-derived here from its figures (independent
    of the core's plan_problems), with the thresholds documented in the README."""
    codes = set()
    n_theta, n_d = report["grid_shape"]
    if report["cells"] < 0.5 * n_theta * n_d:
        codes.add("sparse_grid")
    if min(n_theta, n_d) * report["grid_cell_size_m"] < report["spot_diameter_m"]:
        codes.add("narrow_scan")
    above = sum(n for level, n in report["levels_after"].items() if int(level) > 0)
    if report["unreachable_cells"] > 0:
        codes.add("unreachable_cells")
    if above > report["unreachable_cells"]:
        codes.add("cells_above_level_0")
    if not report["ik"]["solved"]:
        codes.add("arm_cannot_follow")
    t = report.get("trajectory")
    if report["ik"].get("untracked_regions", 0) > 0 or (t and t.get("untracked_regions", 0) > 0):
        codes.add("untracked_regions")
    if t:
        if max(t["max_velocity_ratio"], t["max_acceleration_ratio"]) > 1.001 or \
                t["max_position_violation_rad"] > 1e-9 or t["max_position_violation_m"] > 1e-9:
            codes.add("joint_limits")
        if max(t["max_nozzle_speed_ratio"], t["max_nozzle_accel_ratio"]) > 1.001:
            codes.add("nozzle_limits")
    c = report.get("clearance")
    if c:
        if any(l["fixed"] and l["min_m"] < l["margin_m"] for l in c["links"]):
            codes.add("base_clearance")
        if any(not l["fixed"] and l["min_m"] < l["margin_m"] for l in c["links"]) or \
                c["self"]["samples_below_margin"] > 0:
            codes.add("clearance")
    if (report.get("obstructed") or {}).get("cells", 0) > 0:
        codes.add("obstructed_cells")
    return codes


def test_right_plan_is_status_ok_exit_0(first_run):
    out, _ = first_run
    report = json.loads((out / "report.json").read_text())
    assert report["status"] == "ok" and report["problems"] == []
    assert _problems_from_report(report) == set()
    assert "status: ok" in (out / "report.html").read_text()


def test_bay_at_the_invert_is_refused_with_exit_3(tmp_path):
    """The invert (below the springlines) is out of the arm's reach: the plan is written, marked
    not executable, each problem printed on its own line, exit code 3 (was: exit 0, success)."""
    cfg = tmp_path / "invert.yaml"
    cfg.write_text("synth: {theta_min_rad: -1.5, theta_max_rad: -0.6, length_m: 0.6, points_per_cell: 6}\n")
    out = tmp_path / "inv"
    r = _cli("demo", "--out", out, "--config", cfg)
    assert r.returncode == 3, r.stderr
    report = json.loads((out / "report.json").read_text())
    codes = [p["code"] for p in report["problems"]]
    assert report["status"] == "not_executable" and "arm_cannot_follow" in codes
    assert set(codes) == _problems_from_report(report)
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("not executable: ")]
    assert [ln.rsplit("[", 1)[1].rstrip("]") for ln in lines] == codes
    assert "Traceback" not in r.stderr and "status not_executable" in r.stderr
    html = (out / "report.html").read_text()
    assert "status: not_executable" in html and "the arm cannot follow the plan" in html
    _assert_complete(out)


def test_sparse_scan_is_refused_with_exit_3_and_json_still_printed(tmp_path):
    """400 points spread over a 2 rad x 1.2 m wall: 7 % of the grid's cells hold a point."""
    rng = np.random.default_rng(0)
    theta, d = rng.uniform(0.5, 2.5, 400), rng.uniform(0.0, 1.2, 400)
    cloud = tmp_path / "sparse.xyz"
    np.savetxt(cloud, np.column_stack([d, 5.6 * np.cos(theta), 5.6 * np.sin(theta)]))
    r = _cli("plan", cloud, "--out", tmp_path / "p", "--json")
    assert r.returncode == 3, r.stderr
    report = json.loads(r.stdout)  # --json still prints the whole report
    assert report["status"] == "not_executable"
    assert [p["code"] for p in report["problems"]] == ["sparse_grid"] == sorted(_problems_from_report(report))
    n_theta, n_d = report["grid_shape"]
    assert report["cells"] < 0.5 * n_theta * n_d


def test_a_line_of_points_is_refused_with_exit_3(tmp_path):
    """A line of points along the crown (one row of cells) is no bay: exit 3, narrow_scan."""
    d = np.linspace(0.0, 1.2, 4000)
    cloud = tmp_path / "line.xyz"
    np.savetxt(cloud, np.column_stack([d, 1e-4 * np.sin(50.0 * d), np.full_like(d, 5.7)]))
    cfg = tmp_path / "quick.yaml"
    cfg.write_text("clearance:\n  enabled: false\n")
    r = _cli("plan", cloud, "--out", tmp_path / "p", "--json", "--config", cfg)
    assert r.returncode == 3, r.stderr
    report = json.loads(r.stdout)
    codes = [p["code"] for p in report["problems"]]
    assert "narrow_scan" in codes and set(codes) == _problems_from_report(report)
    assert report["grid_shape"][0] == 1 and "not a bay to spray" in r.stderr


def _exact_link_distance(report_link: dict, robot, q, wall: np.ndarray) -> float:
    """Exact distance (numpy, every wall point) of a link's collision shapes at joint values q."""
    frames = robot.link_frames(q)
    return min(shape_distance(s, frames[s.frame], wall) for s in robot.collision_shapes if s.link == report_link["link"])


def test_clearance_in_the_report_against_an_exact_distance(tmp_path):
    """clearance.enabled: report.json's least distance per link is the exact distance to the wall's
    points at the reported time (checked here with numpy), and no sample is closer (every 25th
    sample checked); a link below its margin is a `clearance` problem and exit 3."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text(TINY_BAY + "clearance: {enabled: true, octree_resolution_m: 0.05}\n")
    out = tmp_path / "c"
    r = _cli("demo", "--out", out, "--config", cfg)
    report = json.loads((out / "report.json").read_text())
    c = report["clearance"]
    assert c["samples"] > 1000 and 0 < c["field_queries"] < c["samples"] * len(c["links"]) and c["wall_queries"] == 0
    below = c["samples_below_margin"]
    assert below == sum(l["samples_below_margin"] for l in c["links"]) + c["self"]["samples_below_margin"]
    codes = [p["code"] for p in report["problems"]]
    assert ("clearance" in codes) == (below > 0)
    assert r.returncode == (3 if report["problems"] else 0), r.stderr
    # Independent distances at the reported times, from the trajectory file and both walls.
    traj = np.load(out / "trajectory.npz")
    robot = shotcrete.load_robot(shotcrete.load_config(cfg))
    wall = np.vstack([shotcrete.read_cloud(out / "surface.ply").xyz, shotcrete.read_cloud(out / "sprayed.ply").xyz])
    for link in c["links"]:
        k = int(np.argmin(np.abs(traj["t_s"] - link["at_time_s"])))
        exact = _exact_link_distance(link, robot, traj["q"][k], wall)
        assert abs(link["min_m"] - exact) <= 1e-6, (link, exact)
        assert "min_lower_m" not in link  # min_m is exact over every sample: no band
        # No sample nearer than min_m (every 25th sample, by numpy).
        for q in traj["q"][::25]:
            assert _exact_link_distance(link, robot, q, wall) >= link["min_m"] - 1e-6, link


@pytest.mark.parametrize("shape, reason", [
    ("plane", "axis fit: the normals are (nearly) parallel; the cloud looks like a plane, not a tunnel wall"),
    ("strip", "axis fit: the wall covers 40.0 deg around the fitted axis, less than profile.min_fit_arc_rad = 150.0 deg; give the axis instead (profile.axis_origin_m, axis_direction)"),
    ("few", "axis fit: need at least 100 points, got 60"),
])
def test_estimate_axis_refuses_a_non_tunnel_in_one_line_exit_2(tmp_path, shape, reason):
    """Issue 16: with profile.estimate_axis a cloud that cannot define a tunnel axis is refused by
    the surface stage, naming the reason, before any plan is made."""
    cfg = tmp_path / "fit.yaml"
    cfg.write_text("profile: {estimate_axis: true}\npreprocess: {voxel_size_m: 0, outlier_neighbors: 0}\n")
    if shape == "plane":  # a flat sheet at crown height
        d, y = np.meshgrid(np.arange(0, 1.2, 0.02), np.arange(-1.5, 1.5, 0.02))
        xyz = np.column_stack([d.ravel(), y.ravel(), np.full(d.size, 5.6)])
    else:  # the design cylinder over 40 degrees (or 60 points of it)
        t, d = np.meshgrid(np.linspace(1.22, 1.92, 80, endpoint=False) + 0.35 / 80, np.arange(0.01, 1.2, 0.02))
        xyz = np.column_stack([d.ravel(), 5.6 * np.cos(t.ravel()), 5.6 * np.sin(t.ravel())])
        if shape == "few":
            xyz = xyz[:: len(xyz) // 60][:60]
    cloud = tmp_path / f"{shape}.xyz"
    np.savetxt(cloud, xyz)
    r = _cli("plan", cloud, "--out", tmp_path / "o", "--config", cfg)
    assert r.returncode == 2, r.stderr
    assert _one_error_line(r.stderr) == f"error: {reason}"
    assert not (tmp_path / "o").exists()
