"""``shotcrete deposition``: fit the spot model to a measured stroke, and the pass spacing.

All numbers come from the C++ core (``read_stroke_csv``, ``fit_stroke``, ``pass_spacing``); this
module only formats them.
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Optional

import typer

from . import _core

PUBLISHED_STROKE_MSE_MM2 = 1.2  # the seed thesis' fit of the same stroke (reference to beat)

deposition_app = typer.Typer(add_completion=False, no_args_is_help=True,
                             help="Deposition model: stroke fit and pass spacing.")


def fit_report(fit, nominal_flow_m3ph: float, rows: int) -> dict:
    """The numbers of a StrokeFit in report units (mm, deg, m^3/h)."""
    m = fit.model
    low = nominal_flow_m3ph * (1.0 - fit.rebound_fraction)
    return {
        "rows": rows,
        "standoff_mm": m.reference_standoff_m * 1e3,
        "speed_mm_s": fit.speed_mps * 1e3,
        "rebound_fraction": fit.rebound_fraction,
        "radius_mm": m.radius_m * 1e3,
        "cone_half_angle_deg": math.degrees(m.cone_half_angle_rad()),
        "spot_beta": m.beta,
        "stroke_exponent": fit.stroke_exponent,
        "q_max_mm_s": m.peak_rate_mps * 1e3,
        "stroke_peak_mm": fit.peak_thickness_m * 1e3,
        "center_offset_mm": fit.center_offset_m * 1e3,
        "mse_mm2": fit.mse_mm2,
        "published_mse_mm2": PUBLISHED_STROKE_MSE_MM2,
        "flow_m3ph": fit.flow_m3ph,
        "deposited_flow_m3ph": fit.deposited_flow_m3ph,
        "nominal_flow_m3ph": nominal_flow_m3ph,
        # The stroke is what stayed on the wall: between nominal * (1 - rebound) and nominal.
        "flow_within_rebound": bool(low <= fit.deposited_flow_m3ph <= nominal_flow_m3ph),
        "evaluations": fit.evaluations,
        "config": {"spot_radius_m": round(m.radius_m, 4), "spot_beta": round(m.beta, 3),
                   "peak_rate_mps": float(f"{m.peak_rate_mps:.3g}")},
    }


def stroke_figure(data, fit, path: Path) -> Path:
    """Measured stroke points against the fitted profile."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    x = np.asarray(data.position_m)
    xs = np.linspace(x.min() - 0.02, x.max() + 0.02, 400)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    ax.plot(xs * 1e3, fit.stroke_at_m(xs) * 1e3, "-", color="tab:blue",
            label=f"fit: R {fit.model.radius_m * 1e3:.1f} mm, beta {fit.model.beta:.3f}")
    ax.plot(x * 1e3, np.asarray(data.thickness_m) * 1e3, "o", color="tab:red", label="measured")
    ax.set_xlabel("position across the pass [mm]")
    ax.set_ylabel("thickness [mm]")
    ax.set_title(f"Stroke at H = {data.standoff_m * 1e3:.0f} mm, v = {data.speed_mps * 1e3:.0f} mm/s: "
                 f"MSE {fit.mse_mm2:.2f} mm$^2$")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def spacing_report(model, target_m: float) -> dict:
    s = _core.pass_spacing(model, target_m)
    return {"target_mm": target_m * 1e3, "spacing_mm": s.spacing_m * 1e3, "overlap_mm": s.overlap_m * 1e3,
            "band_min_mm": s.band_min_m * 1e3, "band_max_mm": s.band_max_m * 1e3,
            "radius_mm": model.radius_m * 1e3, "spot_beta": model.beta}


def _print(result: dict, as_json: bool, keys: list[str]) -> None:
    from .cli import console

    if as_json:
        sys.stdout.write(json.dumps(result, indent=2) + "\n")
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
            figure: Optional[Path] = typer.Option(None, "--figure", help="PNG of measured points vs fitted profile")):
    """Fit the spot model to a measured stroke; prints R, cone angle, beta, q_max, MSE and flow."""
    from .cli import _config, console, user_errors

    with user_errors():
        cfg = _config(config)
        rebound_fraction = cfg.deposition.rebound_fraction if rebound is None else rebound
        data = _core.read_stroke_csv(str(csv), standoff_mm * 1e-3, speed_mm_s * 1e-3, rebound_fraction)
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
    from .cli import _config, user_errors

    with user_errors():
        if not target_mm > 0:
            raise ValueError(f"--target-mm must be > 0, got {target_mm}")
        cfg = _config(config)
        model = _core.spot_model_from_config(cfg.deposition)
        result = spacing_report(model, target_mm * 1e-3)
        _print(result, as_json, ["spacing_mm", "overlap_mm", "band_min_mm", "band_max_mm"])


def register(app: typer.Typer) -> None:
    app.add_typer(deposition_app, name="deposition")
