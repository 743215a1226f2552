"""``shotcrete order``: link regions into one spraying path (the C++ ordering solvers).

Instance file (JSON)::

    {"regions": [{"a": [x, y, z], "b": [x, y, z]}, ...], "start": [x, y, z]}   # start optional, metres

Output with ``--json``: ``{"order", "reversed", "link_length_m", "solve_time_s", "method",
"n_regions", "convergence": {"best", "mean"}}``; ``reversed`` is indexed by region.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Optional

import typer

from . import _core

METHODS = ("aco", "ga", "nn", "exact", "best")


def _point(value, what: str) -> list[float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ValueError(f"{what} must be a list of 3 numbers [x, y, z] in metres, got {value!r}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"{what} must hold numbers, got {v!r}")
        out.append(float(v))
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
    import numpy as np

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
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path} is not valid JSON: {exc}") from None
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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.0))
    x = range(1, len(result.best_per_iteration) + 1)
    ax.plot(x, result.mean_per_iteration, label="mean", color="#999999")
    ax.plot(x, result.best_per_iteration, label="best so far", color="#d7191c")
    ax.axhline(result.link_length_m, ls="--", lw=0.8, color="k", label=f"final {result.link_length_m:.2f} m")
    ax.set_xlabel("generation" if result.method.startswith("ga") else "iteration")
    ax.set_ylabel("link length [m]")
    ax.set_title(f"ordering convergence ({result.method})")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def register(app: typer.Typer) -> None:
    from .cli import _config, console, user_errors

    @app.command()
    def order(instance: Path = typer.Argument(..., metavar="INSTANCE.json",
                                              help='JSON object: "regions", a list of {"a": point, "b": point}, and an '
                                                   'optional "start" point; points are 3 numbers in metres'),
              method: Optional[str] = typer.Option(None, help="aco | ga | nn | exact | best "
                                                               "(default: ordering.method of the config)"),
              seed: Optional[int] = typer.Option(None, help="random seed (default: ordering.seed)"),
              ga_preset: Optional[str] = typer.Option(None, help="published GA parameters: a (Pc 0.9, Pm 0.1, "
                                                                  "400 gen.) or b (Pc 0.2, Pm 0.05, 100 gen.)"),
              local_search: Optional[bool] = typer.Option(None, "--local-search/--no-local-search",
                                                          help="polish with 2-opt/or-opt/flips "
                                                               "(default: ordering.local_search)"),
              config: Optional[Path] = typer.Option(None, help="YAML config file"),
              convergence: Optional[Path] = typer.Option(None, "--convergence-figure",
                                                         help="write a PNG of best/mean length per iteration"),
              as_json: bool = typer.Option(False, "--json", help="print the result as JSON")):
        """Order regions (segments A->B, sprayed either way) for the shortest transit path."""
        with user_errors():
            cfg = _config(config).ordering
            if method is not None:
                if method not in METHODS:
                    raise ValueError(f"--method must be one of {', '.join(METHODS)}, got {method!r}")
                cfg.method = method
            if seed is not None:
                if seed < 0:
                    raise ValueError("--seed must be >= 0")
                cfg.seed = seed
            if ga_preset is not None:
                _core.apply_ga_preset(cfg, ga_preset)
            if local_search is not None:
                cfg.local_search = local_search
            problem = load_instance(instance)
            result = _core.solve_ordering(problem, cfg)
            out = result_json(result, len(problem))
            if convergence is not None:
                if result.best_per_iteration:
                    convergence_figure(result, convergence)
                    out["convergence_figure"] = str(convergence)
                else:
                    console.print(f"[yellow]note:[/yellow] {result.method} has no iterations; "
                                  "no convergence figure written", highlight=False)
            if as_json:
                sys.stdout.write(json.dumps(out, allow_nan=False) + "\n")
                return
            console.print(f"method: {result.method}", highlight=False)
            console.print(f"regions: {len(problem)}", highlight=False)
            console.print(f"link_length_m: {result.link_length_m:.4f}", highlight=False)
            console.print(f"solve_time_s: {result.solve_time_s:.4f}", highlight=False)
            steps = [f"{i}{'<' if result.reversed[i] else '>'}" for i in result.order]
            console.print("order (> A->B, < B->A): " + " ".join(steps), highlight=False)
            if "convergence_figure" in out:
                console.print(f"[green]figure:[/green] {convergence}", highlight=False)
