"""Ordering bindings and the `shotcrete order` CLI (the solvers themselves: tests/cpp/test_ordering.cpp)."""
import itertools
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import shotcrete
from shotcrete import _core
from shotcrete.ordering import problem_from_dict


def bay_problem(n, seed=0, start=False):
    """Rasters along the axis (1.2 m bay) at random arc positions on a 5.6 m half cylinder."""
    rng = np.random.default_rng(seed)
    arc = rng.uniform(0.0, 17.6, n)
    d0, d1 = rng.uniform(0.0, 1.2, n), rng.uniform(0.0, 1.2, n)
    th = arc / 5.6

    def pts(d):
        return np.column_stack([d, 5.6 * np.cos(th), 5.6 * np.sin(th)])

    return _core.OrderingProblem(pts(d0), pts(d1), np.array([0.6, 0.0, 0.0]) if start else None)


def path_length(a, b, start, order, reversed_):
    """Python reference of the cost: exit of one region to the entry of the next (+ start)."""
    total, at = 0.0, start
    for i in order:
        entry, exit_ = (b[i], a[i]) if reversed_[i] else (a[i], b[i])
        if at is not None:
            total += float(np.linalg.norm(entry - at))
        at = exit_
    return total


def brute_force(problem):
    a, b, s = problem.a_m, problem.b_m, problem.start_m
    n = len(a)
    best = math.inf
    for perm in itertools.permutations(range(n)):
        for bits in range(1 << n):
            rev = [(bits >> i) & 1 == 1 for i in range(n)]
            best = min(best, path_length(a, b, s, perm, rev))
    return best


def test_problem_round_trip():
    a = np.arange(6, dtype=float).reshape(2, 3)
    p = _core.OrderingProblem(a, a + 1.0, np.array([1.0, 2.0, 3.0]))
    assert len(p) == 2
    np.testing.assert_array_equal(p.a_m, a)
    np.testing.assert_array_equal(p.b_m, a + 1.0)
    np.testing.assert_array_equal(p.start_m, [1.0, 2.0, 3.0])
    assert _core.OrderingProblem(a, a).start_m is None


@pytest.mark.parametrize("n,start", [(4, False), (5, True), (5, False)])
def test_exact_matches_python_brute_force(n, start):
    p = bay_problem(n, seed=n, start=start)
    r = _core.solve_exact(p)
    assert r.link_length_m == pytest.approx(brute_force(p), abs=1e-9)
    assert r.link_length_m == pytest.approx(path_length(p.a_m, p.b_m, p.start_m, r.order, r.reversed), abs=1e-9)
    assert _core.link_length(p, r.order, r.reversed) == pytest.approx(r.link_length_m, abs=1e-12)


@pytest.mark.parametrize("method", ["aco", "ga", "nn", "exact", "best"])
def test_every_method_returns_a_valid_order(method):
    p = bay_problem(12, seed=3, start=True)
    cfg = shotcrete.load_config().ordering
    cfg.method = method
    r = _core.solve_ordering(p, cfg)
    assert sorted(r.order) == list(range(12))
    assert len(r.reversed) == 12
    assert r.link_length_m >= _core.solve_exact(p).link_length_m - 1e-9
    assert r.link_length_m == pytest.approx(path_length(p.a_m, p.b_m, p.start_m, r.order, r.reversed), abs=1e-9)
    d = r.to_dict()
    assert {"order", "reversed", "link_length_m", "solve_time_s", "method", "convergence"} <= set(d)


def test_seeded_runs_repeat_and_report_convergence():
    p = bay_problem(30, seed=8)
    cfg = shotcrete.load_config().ordering
    cfg.aco_iterations = 25
    cfg.seed = 5
    r1, r2 = _core.solve_aco(p, cfg), _core.solve_aco(p, cfg)
    assert (r1.order, r1.reversed, r1.link_length_m) == (r2.order, r2.reversed, r2.link_length_m)
    assert len(r1.best_per_iteration) == 25 and len(r1.mean_per_iteration) == 25
    assert np.all(np.diff(r1.best_per_iteration) <= 1e-12)
    _core.apply_ga_preset(cfg, "b")
    assert (cfg.ga_crossover, cfg.ga_mutation, cfg.ga_generations) == (0.2, 0.05, 100)
    g = _core.solve_ga(p, cfg)
    assert len(g.best_per_iteration) == 100
    with pytest.raises(ValueError, match="preset"):
        _core.apply_ga_preset(cfg, "z")


def test_local_search_never_worsens():
    p = bay_problem(40, seed=2, start=True)
    nn = _core.solve_nearest_neighbour(p)
    ls = _core.improve_local(p, nn)
    assert ls.link_length_m <= nn.link_length_m + 1e-12
    assert ls.method == "nn+ls"


def test_bad_input_raises_value_error():
    p = bay_problem(4)
    a = p.a_m
    a[2, 1] = np.nan
    with pytest.raises(ValueError, match="region 2"):
        _core.solve_ordering(_core.OrderingProblem(a, p.b_m), shotcrete.load_config().ordering)
    with pytest.raises(ValueError, match="rows"):
        _core.OrderingProblem(np.zeros((3, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="permutation"):
        _core.link_length(p, [0, 0, 1, 2], [False] * 4)
    cfg = shotcrete.load_config().ordering
    with pytest.raises(ValueError, match="method = 'tabu': expected one of aco, ga, nn, exact, best"):
        cfg.method = "tabu"  # refused where it is set, as in YAML
    assert cfg.method == "best"


def write_instance(path, problem):
    data = {"regions": [{"a": list(map(float, a)), "b": list(map(float, b))}
                        for a, b in zip(problem.a_m, problem.b_m)]}
    if problem.start_m is not None:
        data["start"] = list(map(float, problem.start_m))
    path.write_text(json.dumps(data))
    return path


def test_cli_order_json_contract(tmp_path, run_cli):
    p = bay_problem(9, seed=4, start=True)
    inst = write_instance(tmp_path / "inst.json", p)
    r = run_cli("order", inst, "--method", "exact", "--json")
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)
    assert {"order", "reversed", "link_length_m", "solve_time_s"} <= set(out)
    assert out["method"] == "exact" and out["n_regions"] == 9
    assert out["link_length_m"] == pytest.approx(brute_force_bound(p, out), abs=1e-9)
    fig = tmp_path / "conv.png"
    r = run_cli("order", inst, "--method", "aco", "--seed", 3, "--json", "--convergence-figure", fig)
    assert r.exit_code == 0, r.output
    aco = json.loads(r.stdout)
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(aco["convergence"]["best"]) == shotcrete.load_config().ordering.aco_iterations
    assert aco["link_length_m"] >= out["link_length_m"] - 1e-9
    r2 = run_cli("order", inst, "--method", "aco", "--seed", 3, "--json")
    assert json.loads(r2.stdout)["order"] == aco["order"]
    r = run_cli("order", inst, "--method", "ga", "--ga-preset", "b", "--no-local-search")
    assert r.exit_code == 0 and "link_length_m" in r.output


def brute_force_bound(problem, out):
    """The CLI's own numbers re-evaluated in Python: the reported length is the path's length."""
    return path_length(problem.a_m, problem.b_m, problem.start_m, out["order"], out["reversed"])


@pytest.mark.parametrize("text,message", [
    ("{not json", "not valid JSON"),
    ('{"regions": 3}', "regions"),
    ('{"paths": []}', "regions"),
    ('{"regions": [{"a": [0, 0], "b": [1, 0, 0]}]}', "region 0 endpoint a"),
    ('{"regions": [{"a": [0, 0, 0], "b": [1, 0, "x"]}]}', "region 0 endpoint b"),
    ('{"regions": [{"a": [0, 0, 0], "b": [1, 0, 0]}, {"a": [0, 0, 0]}]}', "region 1"),
    ('{"regions": [{"a": [0, 0, 0], "b": [1, 0, NaN]}]}', "region 0 endpoint b"),
    ('{"regions": [], "start": [0, 0]}', "start"),
])
def test_cli_malformed_instance_exits_2(tmp_path, run_cli, text, message):
    inst = tmp_path / "bad.json"
    inst.write_text(text)
    r = run_cli("order", inst)
    assert r.exit_code == 2
    assert message in r.output


def test_cli_bad_options_and_empty_instance(tmp_path, run_cli):
    inst = tmp_path / "empty.json"
    inst.write_text('{"regions": []}')
    r = run_cli("order", inst, "--json")
    assert r.exit_code == 0
    assert json.loads(r.stdout)["order"] == []
    assert run_cli("order", inst, "--method", "tabu").exit_code == 2
    assert run_cli("order", tmp_path / "missing.json").exit_code == 2
    assert run_cli("order", inst, "--ga-preset", "c").exit_code == 2


# ---------------------------------------------------------------- issue 17: safety and scale

HUGE = '{"regions": [{"a": [0, 0, 0], "b": [1, 0, 0]}, {"a": [1e155, 0, 0], "b": [1e155, 1, 0]}]}'
HUGE_MESSAGE = "region 1 endpoint a has x = 1e+155 m, outside the physical range |x| <= 1e+06 m"


@pytest.mark.parametrize("method", ["nn", "aco", "ga", "exact", "best"])
def test_cli_huge_coordinates_exit_2_not_a_crash(tmp_path, method):
    """Issue 17: nn/aco aborted (double free), exact/best printed the invalid order [127, 0]. In a
    child process, so an abort shows as a signal instead of killing pytest."""
    inst = tmp_path / "huge.json"
    inst.write_text(HUGE)
    r = subprocess.run([str(Path(sys.executable).parent / "shotcrete"), "order", str(inst), "--method", method,
                        "--json"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert HUGE_MESSAGE in r.stderr and "Traceback" not in r.stderr
    assert r.stdout == ""


def test_api_huge_or_non_finite_coordinates_raise_value_error():
    cfg = shotcrete.load_config().ordering
    a = np.array([[0.0, 0, 0], [1e155, 0, 0]])
    b = np.array([[1.0, 0, 0], [1e155, 1, 0]])
    for method in ("nn", "aco", "ga", "exact", "best"):
        cfg.method = method
        with pytest.raises(ValueError, match=r"x = 1e\+155 m, outside the physical range"):
            _core.solve_ordering(_core.OrderingProblem(a, b), cfg)
    with pytest.raises(ValueError, match=r"the start point has z = -2e\+06 m"):
        _core.validate_ordering_problem(_core.OrderingProblem(a[:1], b[:1], np.array([0.0, 0.0, -2e6])))
    with pytest.raises(ValueError, match="region 1 endpoint a"):
        problem_from_dict(json.loads(HUGE))
    ok = _core.OrderingProblem(np.array([[0.0, 0, 1e6]]), np.array([[0.0, 1, -1e6]]))
    assert _core.solve_ordering(ok, cfg).order == [0]  # the range includes its limit


def test_large_instance_takes_the_scalable_path_with_progress(tmp_path, run_cli):
    """From 150 regions the default method is nearest neighbour + neighbour-list local search +
    iterated local search (nn+ils): a valid order, shorter than NN, with progress per phase."""
    p = bay_problem(300, seed=8)
    calls = []
    slow = tmp_path / "budget.yaml"  # the kick budget alone: the same order however loaded the machine
    slow.write_text("ordering:\n  time_budget_s: 3600\n")
    cfg = shotcrete.load_config(slow).ordering
    r = _core.solve_ordering(p, cfg, lambda stage, f: calls.append((stage, f)))
    assert r.method == "nn+ils" and sorted(r.order) == list(range(300))
    assert r.link_length_m == pytest.approx(path_length(p.a_m, p.b_m, None, r.order, r.reversed), abs=1e-9)
    assert r.link_length_m < 0.9 * _core.solve_nearest_neighbour(p).link_length_m
    stages = [s for s, _ in calls]
    assert stages[0] == "ordering: nearest neighbour" and calls[-1] == ("ordering: iterated local search", 1.0)
    assert all(0.0 <= f <= 1.0 for _, f in calls)
    inst = write_instance(tmp_path / "large.json", p)
    out = run_cli("order", inst)  # the CLI shows the phases on stderr
    assert out.exit_code == 0, out.output
    assert "ordering: iterated local search" in out.output and "method: nn+ils" in out.output
    out = run_cli("order", inst, "--json", "--config", slow)
    assert json.loads(out.stdout)["order"] == r.order  # same seed, same order
    assert "ordering:" not in out.stdout
