"""Region ordering instances (JSON files) for the C++ ordering solvers, and the convergence figure.

Instance file (JSON)::

    {"regions": [{"a": [x, y, z], "b": [x, y, z]}, ...], "start": [x, y, z]}   # start optional, metres

``result_json`` gives ``{"order", "reversed", "link_length_m", "solve_time_s", "method",
"n_regions", "convergence": {"best", "mean"}}``; ``reversed`` is indexed by region.
"""
from __future__ import annotations

import json
import reprlib
from pathlib import Path

import numpy as np

from . import _core

METHODS = ("aco", "ga", "nn", "exact", "best")


def _shown(value) -> str:
    """``value``'s repr, shortened (reprlib: a few levels and items) so a message stays one readable line."""
    return reprlib.repr(value)


def _point(value, what: str) -> list[float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ValueError(f"{what} must be a list of 3 numbers [x, y, z] in metres, got {_shown(value)}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"{what} must hold numbers, got {_shown(v)}")
        try:
            out.append(float(v))
        except OverflowError:  # a JSON integer of 309 digits or more
            raise ValueError(f"{what}: {_shown(v)} is beyond the range of a float") from None
    return out


def problem_from_dict(data) -> "_core.OrderingProblem":
    """An OrderingProblem from the instance dict; ValueError naming the first bad entry."""
    if not isinstance(data, dict) or "regions" not in data:
        raise ValueError('instance must be a JSON object with a "regions" list')
    regions = data["regions"]
    if not isinstance(regions, list):
        raise ValueError('"regions" must be a list of {"a": [x, y, z], "b": [x, y, z]}')
    unknown = set(data) - {"regions", "start"}
    if unknown:
        raise ValueError(f"unknown instance keys: {', '.join(sorted(unknown))} (expected regions, start)")
    a, b = [], []
    for i, r in enumerate(regions):
        if not isinstance(r, dict) or "a" not in r or "b" not in r:
            raise ValueError(f'region {i} must be an object with "a" and "b" endpoints')
        a.append(_point(r["a"], f"region {i} endpoint a"))
        b.append(_point(r["b"], f"region {i} endpoint b"))
    start = data.get("start")
    start = None if start is None else _point(start, "start")
    shape = (len(a), 3)
    problem = _core.OrderingProblem(np.asarray(a, dtype=float).reshape(shape),
                                    np.asarray(b, dtype=float).reshape(shape),
                                    None if start is None else np.asarray(start, dtype=float))
    _core.validate_ordering_problem(problem)  # NaN / inf, named by region
    return problem


def load_instance(path: Path) -> "_core.OrderingProblem":
    """Read an instance JSON file (see the module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"instance file {path} not found")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError, an integer beyond 4300 digits
        raise ValueError(f"{path} is not valid JSON: {exc}") from None
    except RecursionError:  # json nests its decoder once per array or object level
        raise ValueError(f"{path} is not valid JSON for an instance: arrays or objects nested too deeply") from None
    try:
        return problem_from_dict(data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def result_json(result, n_regions: int) -> dict:
    out = result.to_dict()
    out["n_regions"] = n_regions
    return out


def convergence_figure(result, path: Path) -> Path:
    """Best-so-far and mean path length per iteration (ACO) or generation (GA)."""
    from . import plots  # here, not at the top: `import shotcrete` stays free of matplotlib

    plt = plots.plt

    fig, ax = plt.subplots(figsize=(6.5, 4.0))
    x = range(1, len(result.best_per_iteration) + 1)
    ax.plot(x, result.mean_per_iteration, label="mean", color="#999999")
    ax.plot(x, result.best_per_iteration, label="best so far", color="#d7191c")
    ax.axhline(result.link_length_m, ls="--", lw=0.8, color="k", label=f"final {result.link_length_m:.2f} m")
    ax.set_xlabel("generation" if result.method.startswith("ga") else "iteration")
    ax.set_ylabel("link length [m]")
    ax.set_title(f"ordering convergence ({result.method})")
    ax.legend()
    return plots.save(fig, path)
