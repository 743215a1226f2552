"""Design cross-sections: read a section drawn in a DXF (one LWPOLYLINE or POLYLINE, read with
ezdxf), write it in the project's CSV (``y_m,z_m,bulge``, the format ``profile.section_path`` and
the ROS node read), and describe a section (the core's ``DesignProfile``: span, arc length, the
radius it stands for) with a figure of it."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from . import _core

UNIT_SCALE = {"m": 1.0, "cm": 0.01, "mm": 0.001}


def read_dxf_section(path: str | Path, layer: str | None = None, units: str = "m",
                     origin: tuple[float, float] = (0.0, 0.0), mirror: bool = False) -> list[_core.SectionVertex]:
    """Vertices of the one polyline of a DXF's modelspace (on ``layer`` when given). The drawing's X
    maps to y (the frame's ey), its Y to z; ``origin`` is where the tunnel axis lies in the drawing
    (drawing units), ``units`` the drawing's unit, ``mirror`` flips X (a section drawn looking
    against the frame's ey). ValueError, one line, for an unreadable file, no or several polylines."""
    import ezdxf  # PyPI; only needed for DXF sections
    from ezdxf import recover

    if units not in UNIT_SCALE:
        raise ValueError(f"--units {units!r}: expected one of m, cm, mm")
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such DXF file")
    try:
        doc, auditor = recover.readfile(str(path))
    except (IOError, ezdxf.DXFStructureError) as exc:
        raise ValueError(f"{path}: not a readable DXF ({exc})") from None
    query = "LWPOLYLINE POLYLINE" + (f'[layer=="{layer}"]' if layer else "")
    lines = list(doc.modelspace().query(query))
    where = f" on layer {layer!r}" if layer else ""
    if not lines:
        raise ValueError(f"{path}: no LWPOLYLINE or POLYLINE{where}; draw the section as one polyline")
    if len(lines) > 1:
        raise ValueError(f"{path}: {len(lines)} polylines{where}; keep one (or pick its layer with --layer)")
    entity = lines[0]
    if entity.dxftype() == "LWPOLYLINE":
        pts = [(x, y, b) for x, y, b in entity.get_points("xyb")]
        closed = entity.closed
    else:
        pts = [(v.dxf.location.x, v.dxf.location.y, v.dxf.get("bulge", 0.0)) for v in entity.vertices]
        closed = entity.is_closed
    if closed:
        raise ValueError(f"{path}: the polyline is closed; give the sprayed part only, from one foot over the crown "
                         "to the other (the invert is not sprayed)")
    scale, sign = UNIT_SCALE[units], (-1.0 if mirror else 1.0)
    # Mirroring reverses the turning sense of every arc.
    return [_core.SectionVertex((x - origin[0]) * scale * sign, (y - origin[1]) * scale, b * sign) for x, y, b in pts]


def read_section(path: str | Path, **dxf_options) -> list[_core.SectionVertex]:
    """Vertices of a section file: .dxf (``read_dxf_section`` with ``dxf_options``) or the CSV
    (``_core.read_section_csv``; the DXF options do not apply)."""
    if Path(path).suffix.lower() == ".dxf":
        return read_dxf_section(path, **dxf_options)
    return _core.read_section_csv(str(path))


def write_section_csv(vertices, path: str | Path, source: str = "") -> Path:
    """The CSV ``profile.section_path`` reads."""
    path = Path(path)
    lines = ["# design section (y_m along the job frame's ey, z_m up, m from the tunnel axis; "
             "bulge = tan(included angle / 4) to the next vertex, ccw > 0)"]
    if source:
        lines.append(f"# from {source}")
    lines.append("y_m,z_m,bulge")
    lines += [f"{v.y_m:.6f},{v.z_m:.6f},{v.bulge:.8f}" for v in vertices]
    path.write_text("\n".join(lines) + "\n")
    return path


def describe(profile) -> dict:
    """What a section is: its span of theta (from the right springline, ccw), its arc length, the
    mean radius the grid's theta step uses, its least and largest distance from the axis."""
    poly = np.asarray(profile.polyline_m)
    dist = np.hypot(poly[:, 0], poly[:, 1])
    length = float(np.sum(np.hypot(*np.diff(poly, axis=0).T)))
    return {"theta_min_deg": math.degrees(profile.theta_min_rad), "theta_max_deg": math.degrees(profile.theta_max_rad),
            "arc_length_m": length, "mean_radius_m": profile.radius_m,
            "min_radius_m": float(dist.min()), "max_radius_m": float(dist.max()), "chords": len(poly) - 1}


def plot_section(profile, path: str | Path, title: str = "") -> Path:
    """The section in its plane with the axis and the rays at its ends (a figure for the user)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    poly = np.asarray(profile.polyline_m)
    fig, ax = plt.subplots(figsize=(6, 5))
    ax.plot(poly[:, 0], poly[:, 1], "k-", lw=2, label="design line")
    for th in (profile.theta_min_rad, profile.theta_max_rad, math.pi / 2):
        r = profile.radius_at(th)
        ax.plot([0, r * math.cos(th)], [0, r * math.sin(th)], color="0.6", lw=0.8, ls="--")
    ax.plot([0], [0], "r+", ms=12, label="tunnel axis")
    ax.set_aspect("equal")
    ax.set_xlabel("y [m] (frame ey)")
    ax.set_ylabel("z [m] (up)")
    ax.set_title(title or "design section")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower center")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)
