"""``shotcrete deposition``: fit the spot model to a measured stroke, and the pass spacing
(shotcrete.deposition)."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from . import _core
from .cli_common import cli_config, console, print_json, refuse_overwrite, user_errors
from .deposition import fit_report, read_stroke_csv, spacing_report, stroke_figure

deposition_app = typer.Typer(add_completion=False, no_args_is_help=True,
                             help="Deposition model: stroke fit and pass spacing.")


def _print(result: dict, as_json: bool, keys: list[str]) -> None:
    if as_json:
        print_json(result, indent=2)
        return
    for key in keys:
        value = result[key]
        console.print(f"{key}: {value:.4g}" if isinstance(value, float) else f"{key}: {value}", highlight=False)


@deposition_app.command("fit")
def fit_cmd(csv: Path = typer.Argument(..., metavar="CSV", help="position_mm,thickness_mm across one pass"),
            standoff_mm: float = typer.Option(1000.0, "--standoff-mm", help="nozzle standoff of the test [mm]"),
            speed_mm_s: float = typer.Option(150.0, "--speed-mm-s", help="nozzle speed of the test [mm/s]"),
            rebound: Optional[float] = typer.Option(None, "--rebound",
                                                    help="rebound fraction (default: deposition.rebound_fraction)"),
            config: Optional[Path] = typer.Option(None, help="YAML config file"),
            as_json: bool = typer.Option(False, "--json", help="print the fit as JSON"),
            figure: Optional[Path] = typer.Option(None, "--figure", help="PNG of measured points vs fitted profile"),
            force: bool = typer.Option(False, "--force", help="overwrite an existing figure file")):
    """Fit the spot model to a measured stroke; prints R, cone angle, beta, q_max, MSE and flow."""
    with user_errors():
        refuse_overwrite(figure, force, "--figure")
        cfg = cli_config(config)
        rebound_fraction = cfg.deposition.rebound_fraction if rebound is None else rebound
        data = read_stroke_csv(csv, standoff_mm * 1e-3, speed_mm_s * 1e-3, rebound_fraction)
        fit = _core.fit_stroke(data)
        result = fit_report(fit, cfg.deposition.nominal_flow_m3ph, len(data))
        if figure is not None:
            result["figure"] = str(stroke_figure(data, fit, figure))
        _print(result, as_json, ["radius_mm", "cone_half_angle_deg", "spot_beta", "stroke_exponent", "q_max_mm_s",
                                 "stroke_peak_mm", "center_offset_mm", "mse_mm2", "flow_m3ph",
                                 "deposited_flow_m3ph", "flow_within_rebound"])
        if not as_json and figure is not None:
            console.print(f"figure: {figure}")


@deposition_app.command("spacing")
def spacing_cmd(target_mm: float = typer.Option(..., "--target-mm", help="single-pass peak thickness Td [mm]"),
                config: Optional[Path] = typer.Option(None, help="YAML config file (deposition section)"),
                as_json: bool = typer.Option(False, "--json", help="print as JSON")):
    """Golden-section pass spacing of the config's spot model for a target thickness."""
    with user_errors():
        if not target_mm > 0:
            raise ValueError(f"--target-mm must be > 0, got {target_mm}")
        cfg = cli_config(config)
        model = _core.spot_model_from_config(cfg.deposition)
        result = spacing_report(model, target_mm * 1e-3)
        _print(result, as_json, ["spacing_mm", "overlap_mm", "band_min_mm", "band_max_mm"])


def register(app: typer.Typer) -> None:
    app.add_typer(deposition_app, name="deposition")
