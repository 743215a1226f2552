"""``shotcrete order``: link regions into one spraying path (the C++ ordering solvers; the instance
file is described in shotcrete.ordering)."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from . import _core
from .cli_common import cli_config, console, print_json, progress_reporter, refuse_overwrite, say, user_errors
from .ordering import METHODS, convergence_figure, load_instance, result_json


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
          as_json: bool = typer.Option(False, "--json", help="print the result as JSON"),
          force: bool = typer.Option(False, "--force", help="overwrite an existing figure file")):
    """Order regions (segments A->B, sprayed either way) for the shortest transit path."""
    with user_errors():
        refuse_overwrite(convergence, force, "--convergence-figure")
        cfg = cli_config(config).ordering
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
        with progress_reporter(disable=as_json) as progress:  # long runs (large n) show their phases
            result = _core.solve_ordering(problem, cfg, progress)
        out = result_json(result, len(problem))
        if convergence is not None:
            if result.best_per_iteration:
                convergence_figure(result, convergence)
                out["convergence_figure"] = str(convergence)
            else:
                say("note:", f"{result.method} has no iterations; no convergence figure written", "yellow")
        if as_json:
            print_json(out, allow_nan=False)
            return
        console.print(f"method: {result.method}", highlight=False)
        console.print(f"regions: {len(problem)}", highlight=False)
        console.print(f"link_length_m: {result.link_length_m:.4f}", highlight=False)
        console.print(f"solve_time_s: {result.solve_time_s:.4f}", highlight=False)
        steps = [f"{i}{'<' if result.reversed[i] else '>'}" for i in result.order]
        console.print("order (> A->B, < B->A): " + " ".join(steps), highlight=False)
        if "convergence_figure" in out:
            say("figure:", str(convergence), "green")


def register(app: typer.Typer) -> None:
    app.command()(order)
