"""``shotcrete rescan BEFORE AFTER --job DIR``: the closed loop after spraying (rescan.py)."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from . import _core
from .cli_common import cli_config, console, print_json, progress_reporter, refuse_overwrite, say, user_errors
from .config import default_config_path
from .io import read_cloud

SUMMARY = ("registration", "cells_measured", "thickness_mm", "measured_vs_predicted_mm", "calibration")


def register(app: typer.Typer) -> None:
    @app.command()
    def rescan(before_path: Path = typer.Argument(..., metavar="BEFORE", help="the scan the job planned on (with its surroundings)"),
               after_path: Path = typer.Argument(..., metavar="AFTER", help="the scan after spraying, any scanner pose near BEFORE's"),
               job: Path = typer.Option(..., "--job", help="output directory of `shotcrete plan` / `demo` for this bay"),
               out: Path = typer.Option(Path("out/rescan"), "--out", help="output directory"),
               config: Optional[Path] = typer.Option(None, help="YAML config file (the job's)"),
               units: str = typer.Option("m", help="units of both clouds: m, cm or mm"),
               reference: Optional[str] = typer.Option(None, help="dry | box | mask (default rescan.reference)"),
               mask: Optional[Path] = typer.Option(None, help="mask cloud for --reference mask (before frame)"),
               initial_pose: Optional[Path] = typer.Option(None, "--initial-pose",
                                                           help="JSON 4x4 after -> before start pose (default identity)"),
               correct: bool = typer.Option(True, "--correct/--no-correct", help="plan the corrective round"),
               per_point: int = typer.Option(0, "--per-point", min=0,
                                             help="also measure at up to N wall points of BEFORE (points.ply, intensity = layer in m)"),
               write_config: Optional[Path] = typer.Option(None, "--write-config",
                                                           help="write a copy of the config with the calibrated deposition rate"),
               force: bool = typer.Option(False, help="overwrite an existing --write-config file"),
               as_json: bool = typer.Option(False, "--json", help="print report.json to stdout")):
        """Register AFTER to BEFORE on unsprayed areas, measure the layer per cell, calibrate the flow
        and plan the corrective round; writes report.json/report.html to OUT."""
        from . import rescan as rs
        from .outdir import job_output
        from .rescan import read_pose

        with user_errors():
            refuse_overwrite(write_config, force, "--write-config")
            cfg = cli_config(config, units)
            if reference is not None:
                cfg.rescan.reference = reference
            if cfg.rescan.reference == "mask" and mask is None:
                raise ValueError("--reference mask needs --mask FILE")
            the_job = rs.read_job(job, cfg)
            T0 = read_pose(initial_pose) if initial_pose is not None else None
            inputs = [p for p in (before_path, after_path, mask, initial_pose, config) if p is not None]
            with job_output(out, inputs) as tmp:
                before, after = read_cloud(before_path), read_cloud(after_path)
                for path, cloud in ((before_path, before), (after_path, after)):
                    try:
                        _core.check_cloud(cloud, cfg.io)
                    except ValueError as exc:
                        raise ValueError(f"{path}: {exc}") from None
                mask_cloud = read_cloud(mask) if mask is not None else None
                with progress_reporter(disable=as_json) as progress:
                    result = rs.rescan(before, after, the_job, cfg, mask=mask_cloud, initial=T0, correct=correct,
                                       per_point=per_point, progress=progress)
                result.summary["inputs"] = {"before": str(before_path), "after": str(after_path),
                                            "config": str(config or default_config_path())}
                rs.write_outputs(tmp, result)
            if write_config is not None and result.calibrated is not None:
                Path(write_config).write_text(result.calibrated.to_yaml())
                result.summary["config_written"] = str(write_config)
            elif write_config is not None:
                raise ValueError(f"--write-config: no calibrated factor ({result.summary['calibration'].get('error')})")
            if as_json:
                print_json(result.summary, indent=2, default=float)
            else:
                for key in SUMMARY:
                    console.print(f"{key}: {result.summary[key]}", highlight=False)
                if "correction" in result.summary:
                    c = result.summary["correction"]
                    console.print(f"correction: {c.get('rounds')} rounds, residual_mm {c.get('residual_mm')}", highlight=False)
                say("report:", str(Path(out) / "report.html"), "green")
