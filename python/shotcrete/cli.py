"""The ``shotcrete`` command line: synth, demo, plan (and the stage tools registered below)."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from . import cli_deposition, cli_order, cli_rescan, cli_robot, cli_section, synthetic_cloud
from .cli_common import (EXIT_NOT_EXECUTABLE, cli_config, console, print_json, progress_reporter, refuse_overwrite, say,
                         user_errors)
from .config import default_config_path
from ._core import make_synthetic_bay
from .io import read_cloud, write_cloud
from .pipeline import run_job

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="Shotcrete spraying plans from a 3-D scan of a tunnel bay.")


def _emit(result: dict, as_json: bool, summary_keys: list[str]) -> None:
    if as_json:
        print_json(result, indent=2, default=float)
        return
    for key in summary_keys:
        if key in result:
            console.print(f"{key}: {result[key]}", highlight=False)


def _verdict(result: dict, out: Path, as_json: bool) -> None:
    """The report's path, or, for a plan that is not right, each problem on its own line and exit
    code 3: the outputs are written (the partial result, marked in report.json) but no success."""
    if result.get("status", "ok") == "ok":
        if not as_json:
            say("report:", str(Path(out) / "report.html"), "green")
        return
    for problem in result["problems"]:
        say("not executable:", f"{problem['message']} [{problem['code']}]", "red")
    say("report:", f"{Path(out) / 'report.html'} (status {result['status']})", "red")
    raise typer.Exit(EXIT_NOT_EXECUTABLE)


def _run_job(cloud, config, out: Path, as_json: bool, inputs: dict) -> dict:
    with progress_reporter(disable=as_json) as progress:
        result = run_job(cloud, config, out, progress, inputs=inputs)
    result["report_html"] = str(Path(out) / "report.html")
    return result


TUNE_HELP = ("tune the timing of every region by particle swarm (timing.tune_with_pso); kept when faster "
             "within the same joint limits")
SUMMARY = ["status", "local_origin_m", "cells", "levels_before", "levels_after", "rounds", "passes", "residual_mm", "spray_time_s",
           "total_time_s", "spray_time_ratio", "report_html"]


@app.command()
def synth(out: Path = typer.Option(..., "--out", help="cloud file to write (.pcd, .ply, .xyz, .las)"),
          seed: Optional[int] = typer.Option(None, help="random seed (default: synth.seed of the config)"),
          config: Optional[Path] = typer.Option(None, help="YAML config file"),
          force: bool = typer.Option(False, help="overwrite an existing file"),
          after: Optional[Path] = typer.Option(None, "--after", metavar="JOBDIR",
                                               help="the scan after the job in JOBDIR sprayed the bay (synth.after_*); "
                                                    "ground truth in <stem>_truth.json/.csv beside it")):
    """Write the synthetic bay (half cylinder with dig pits; with synth.context_enabled its unsprayed
    surroundings) as a point cloud, or with --after the same bay after spraying."""
    with user_errors():
        refuse_overwrite(out, force, "--out")
        cfg = cli_config(config)
        if seed is not None:
            if seed < 0:
                raise ValueError("--seed must be >= 0")
            cfg.synth.seed = seed
        if after is None:
            cloud = make_synthetic_bay(cfg.synth).sample_scan(cfg.grid.cell_size_m)
            write_cloud(out, cloud)
            console.print(f"wrote {len(cloud)} points to {out}")
            return
        from . import rescan as rs

        for suffix in ("_truth.json", "_truth.csv"):
            refuse_overwrite(out.with_name(out.stem + suffix), force, "--out (its truth file)")
        job = rs.read_job(after, cfg)
        scan = rs.after_scan(job, cfg)
        write_cloud(out, scan.cloud)
        truth = rs.write_after_truth(out, job, scan, cfg)
        console.print(f"wrote {len(scan.cloud)} points to {out}, ground truth to {truth[0]} and {truth[1]}")


@app.command()
def demo(out: Path = typer.Option(Path("out/demo"), "--out", help="output directory"),
         config: Optional[Path] = typer.Option(None, help="YAML config file"),
         as_json: bool = typer.Option(False, "--json", help="print report.json to stdout"),
         tune_timing: bool = typer.Option(False, "--tune-timing", help=TUNE_HELP)):
    """Plan and simulate the built-in synthetic bay; writes report.json/report.html to OUT."""
    with user_errors():
        cfg = cli_config(config)
        cfg.timing.tune_with_pso = cfg.timing.tune_with_pso or tune_timing
        result = _run_job(lambda: synthetic_cloud(cfg), cfg, out, as_json, {"config": config or default_config_path()})
        _emit(result, as_json, SUMMARY)
        _verdict(result, out, as_json)


@app.command()
def plan(cloud_path: Path = typer.Argument(..., metavar="CLOUD", help=".pcd .ply .xyz .las .laz .e57 in metres"),
         out: Path = typer.Option(Path("out/plan"), "--out", help="output directory"),
         config: Optional[Path] = typer.Option(None, help="YAML config file"),
         units: str = typer.Option("m", help="units of the cloud coordinates: m, cm or mm"),
         as_json: bool = typer.Option(False, "--json", help="print report.json to stdout"),
         tune_timing: bool = typer.Option(False, "--tune-timing", help=TUNE_HELP)):
    """Plan a scanned bay; writes report.json/report.html, the plan and the sprayed cloud to OUT."""
    with user_errors():
        cfg = cli_config(config, units)
        cfg.timing.tune_with_pso = cfg.timing.tune_with_pso or tune_timing
        result = _run_job(lambda: read_cloud(cloud_path), cfg, out, as_json, {"cloud": cloud_path, "config": config or default_config_path()})
        _emit(result, as_json, SUMMARY)
        _verdict(result, out, as_json)


# The stage tools, listed after synth, demo and plan.
cli_order.register(app)
cli_deposition.register(app)
cli_robot.register(app)
cli_rescan.register(app)
cli_section.register(app)


def main() -> None:  # pragma: no cover - console entry point alias
    app()


if __name__ == "__main__":  # pragma: no cover
    app()
