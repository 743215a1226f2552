"""The deposition model in report units: the spot model fitted to a measured stroke, the pass
spacing, and the stroke figure (``shotcrete deposition`` and bench/bench_deposition.py).

All numbers come from the C++ core (``read_stroke_csv``, ``fit_stroke``, ``pass_spacing``); this
module only checks the CSV is text, converts and draws them.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from . import _core
from .io import check_text

PUBLISHED_STROKE_MSE_MM2 = 1.2  # the seed thesis' fit of the same stroke (reference to beat)


def read_stroke_csv(path: Path, standoff_m: float, speed_mps: float, rebound_fraction: float):
    """The core's ``read_stroke_csv`` of a file checked to be text first (io.check_text): the core
    quotes a bad cell in its message, and a cell of non-UTF-8 bytes made an empty ValueError, a
    carriage return inside a cell a line that overwrote itself."""
    path = Path(path)
    if path.is_file():  # else the core names the file it cannot open
        check_text(path.read_bytes(), path)
    return _core.read_stroke_csv(str(path), standoff_m, speed_mps, rebound_fraction)


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
    from . import plots  # here, not at the top: `import shotcrete` stays free of matplotlib

    plt = plots.plt

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
    return plots.save(fig, path, dpi=120)


def spacing_report(model, target_m: float) -> dict:
    s = _core.pass_spacing(model, target_m)
    return {"target_mm": target_m * 1e3, "spacing_mm": s.spacing_m * 1e3, "overlap_mm": s.overlap_m * 1e3,
            "band_min_mm": s.band_min_m * 1e3, "band_max_mm": s.band_max_m * 1e3,
            "radius_mm": model.radius_m * 1e3, "spot_beta": model.beta}
