"""``shotcrete section FILE``: check a design cross-section (CSV or DXF), convert a DXF to the CSV
``profile.section_path`` reads, and draw it."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from . import _core
from .cli_common import console, print_json, refuse_overwrite, say, user_errors


def register(app: typer.Typer) -> None:
    @app.command()
    def section(path: Path = typer.Argument(..., metavar="FILE", help="design section: .csv (y_m,z_m[,bulge]) or .dxf"),
                out: Optional[Path] = typer.Option(None, "--out", help="write the section as CSV (for profile.section_path)"),
                plot: Optional[Path] = typer.Option(None, "--plot", help="draw the section (.png)"),
                layer: Optional[str] = typer.Option(None, help="DXF: layer of the section's polyline"),
                units: str = typer.Option("m", help="DXF: drawing units (m, cm, mm)"),
                origin: str = typer.Option("0,0", help="DXF: where the tunnel axis lies in the drawing, 'X,Y'"),
                mirror: bool = typer.Option(False, help="DXF: flip X (drawn looking the other way)"),
                force: bool = typer.Option(False, help="overwrite existing --out / --plot files"),
                as_json: bool = typer.Option(False, "--json", help="print the description as JSON")):
        """Read and check a design section; print its span, arc length and radii (exit 2 when it
        cannot be a design section: not star-shaped about the axis, crossing the invert, malformed)."""
        from . import section as sec

        with user_errors():
            try:
                ox, oy = (float(v) for v in origin.split(","))
            except ValueError:
                raise ValueError(f"--origin {origin!r}: expected 'X,Y'") from None
            verts = sec.read_section(path, layer=layer, units=units, origin=(ox, oy), mirror=mirror)
            profile = _core.DesignProfile.from_section(verts)
            refuse_overwrite(out, force, "--out")
            refuse_overwrite(plot, force, "--plot")
            if out is not None and out.resolve() == path.resolve():
                raise ValueError(f"--out {out} is the input file")
            facts = sec.describe(profile)
            if out is not None:
                facts["csv"] = str(sec.write_section_csv(verts, out, source=str(path)))
            if plot is not None:
                facts["plot"] = str(sec.plot_section(profile, plot, title=path.name))
            if as_json:
                print_json(facts, indent=2)
                return
            console.print(f"section {path}: theta {facts['theta_min_deg']:.1f} .. {facts['theta_max_deg']:.1f} deg, "
                          f"arc {facts['arc_length_m']:.3f} m, mean radius {facts['mean_radius_m']:.3f} m "
                          f"(from the axis {facts['min_radius_m']:.3f} .. {facts['max_radius_m']:.3f} m)", highlight=False)
            for key in ("csv", "plot"):
                if key in facts:
                    say(f"{key}:", facts[key], "green")
