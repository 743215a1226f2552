"""report.json and report.html for a job directory."""
from __future__ import annotations

import csv
import hashlib
import html
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import _core


def _sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def provenance(config, cloud, inputs: dict[str, Path]) -> dict:
    """report.json's ``provenance``: the program version, sha256 of each input file by role
    ("cloud", "config"), of the config the job ran with (after --units / --tune-timing; for the demo
    it holds the generated bay's parameters, synth.*) and of the points planned on (float64 x y z)."""
    from . import __version__

    points = np.ascontiguousarray(np.asarray(cloud.xyz, dtype=np.float64))
    return {"program": "shotcrete-planner", "version": __version__,
            "inputs": {role: {"path": str(Path(p).resolve()), "sha256": _sha256_file(p)} for role, p in inputs.items()},
            "config_effective_sha256": hashlib.sha256(config.to_yaml().encode()).hexdigest(),
            "points": len(points), "points_sha256": hashlib.sha256(points.tobytes()).hexdigest()}


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, float) and value != value:
        return None
    return value


def write_json(path: Path, data: dict) -> Path:
    path.write_text(json.dumps(_jsonable(data), indent=2) + "\n")
    return path


# ---------------------------------------------------------------------------------------------
# report.html: the summary a site engineer reads first, the 3-D view, the figures, the raw figures.

# The level-0 band of the core's levels (level_of_td_mm: -50 mm <= TD < 50 mm is level 0). The core's
# verdict (plan_problems: no cell left above level 0) and the class map use it; a test checks it
# against _core.level_of_td_mm.
LEVEL0_TOLERANCE_MM = 50.0

CSV_COLUMNS = ("cell", "row", "col", "theta_rad", "s_m", "d_m", "td_before_mm", "deposit_planned_mm",
               "deposit_executed_mm", "residual_mm", "level")


@dataclass
class CellTable:
    """The valid cells of the grid with the core's values: geometry (cell centres: theta from the
    right springline, s = theta * r_design along the arc, d along the axis), TD before, deposit of
    the plan (TD before - plan.td_after) and of the executed trajectory (TD before -
    executed.td_after; NaN without a trajectory), residual (TD after of ``source``: executed when
    there is a trajectory, else planned) and its level (_core.level_of_td_mm). Thicknesses in m."""
    cell: np.ndarray
    row: np.ndarray
    col: np.ndarray
    theta_rad: np.ndarray
    s_m: np.ndarray
    d_m: np.ndarray
    td_before_m: np.ndarray
    deposit_planned_m: np.ndarray
    deposit_executed_m: np.ndarray
    residual_m: np.ndarray
    level: np.ndarray
    source: str

    def levels_full(self, n_cells: int) -> list[int]:
        """Level per grid cell (NO_DATA_LEVEL where the scan has no data), as the core's functions take it."""
        out = np.full(n_cells, _core.NO_DATA_LEVEL, dtype=int)
        out[self.cell] = self.level
        return out.tolist()


def cell_table(surface, plan, executed=None) -> CellTable:
    grid = surface.grid
    cells = np.flatnonzero(np.asarray(grid.valid).reshape(-1))
    rows, cols = cells // grid.n_d, cells % grid.n_d
    theta = grid.theta0_rad + (rows + 0.5) * grid.dtheta_rad  # Grid::theta_center
    before = np.asarray(grid.td_m).reshape(-1)[cells]
    planned_after = np.asarray(plan.td_after_m)[cells]
    executed_after = np.asarray(executed.td_after_m)[cells] if executed is not None else np.full(len(cells), np.nan)
    after = executed_after if executed is not None else planned_after
    level = np.array([_core.level_of_td_mm(x * 1000.0) for x in after], dtype=int)
    return CellTable(cells, rows, cols, theta, theta * grid.profile.radius_m,
                     grid.d0_m + (cols + 0.5) * grid.cell_size_m,  # Grid::d_center
                     before, before - planned_after, before - executed_after, after, level,
                     "executed" if executed is not None else "planned")


def write_cells_csv(path: Path, table: CellTable) -> Path:
    """cells.csv: one row per valid cell (CSV_COLUMNS; thicknesses in mm, positive TD: concrete
    missing; deposit_executed_mm empty without a trajectory)."""
    mm = lambda a: np.round(np.asarray(a) * 1000.0, 2)  # noqa: E731
    cols = [table.cell, table.row, table.col, np.round(table.theta_rad, 6), np.round(table.s_m, 4),
            np.round(table.d_m, 4), mm(table.td_before_m), mm(table.deposit_planned_m),
            mm(table.deposit_executed_m), mm(table.residual_m), table.level]
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(CSV_COLUMNS)
        for values in zip(*cols):
            writer.writerow(["" if isinstance(v, float) and v != v else v for v in (x.item() for x in values)])
    return path


def _wall_part(theta_rad: float) -> str:
    deg = np.degrees(theta_rad)
    if deg < -10:
        return "below the right springline"
    if deg < 20:
        return "right springline"
    if deg < 70:
        return "right haunch"
    if deg <= 110:
        return "crown"
    if deg <= 160:
        return "left haunch"
    if deg <= 190:
        return "left springline"
    return "below the left springline"


def off_regions(surface, table: CellTable, missing: bool) -> list[dict]:
    """Where cells are off after spraying: the 4-connected groups (_core.find_regions) of the cells
    missing more than the level-0 band (level >= 1; ``missing``) or over-filled beyond it (level
    -1), largest first, each with its cells, the wall part, d and s ranges [m] and worst residual [mm]."""
    grid = surface.grid
    off = table.level >= 1 if missing else table.level == -1
    if not off.any():
        return []
    flags = np.full(grid.n_theta * grid.n_d, _core.NO_DATA_LEVEL, dtype=int)
    flags[table.cell] = 0
    flags[table.cell[off]] = 1
    residual = dict(zip(table.cell.tolist(), table.residual_m.tolist()))
    out = []
    for reg in _core.find_regions(grid, flags.tolist(), 1, 1):
        worst = max((residual[c] for c in reg.cells), key=abs) * 1000.0
        theta_mid = grid.theta0_rad + (0.5 * (reg.row_min + reg.row_max) + 0.5) * grid.dtheta_rad
        r, cs = grid.profile.radius_m, grid.cell_size_m
        out.append({"cells": len(reg.cells), "part": _wall_part(theta_mid),
                    "d_m": (grid.d0_m + reg.col_min * cs, grid.d0_m + (reg.col_max + 1) * cs),
                    "s_m": ((grid.theta0_rad + reg.row_min * grid.dtheta_rad) * r,
                            (grid.theta0_rad + (reg.row_max + 1) * grid.dtheta_rad) * r),
                    "worst_mm": worst})
    return sorted(out, key=lambda g: -g["cells"])


@dataclass
class PageFacts:
    """What the summary shows beside report.json: the bay's length (the grid along the axis), the
    planner's finish tolerance and the cells within it, where cells are off, the 3-D view."""
    bay_length_m: float
    cell_size_m: float
    finish_tolerance_mm: float
    cells_within_finish: int
    missing_regions: list = field(default_factory=list)
    over_regions: list = field(default_factory=list)
    view_html: str = ""


def page_facts(surface, table: CellTable, config, view_html: str = "") -> PageFacts:
    grid = surface.grid
    tol_mm = config.planner.finish_tolerance_m * 1000.0
    return PageFacts(grid.n_d * grid.cell_size_m, grid.cell_size_m, tol_mm,
                     int(np.count_nonzero(np.abs(table.residual_m) * 1000.0 <= tol_mm)),
                     off_regions(surface, table, True), off_regions(surface, table, False), view_html)


def _bay_note(bay) -> str:
    """Where the bay lies in the scan when the scan holds more than the bay (grid.bay)."""
    if not bay:
        return ""
    whole = abs(bay["start_m"] - bay["scan_start_m"]) < 1e-9 and abs(bay["end_m"] - bay["scan_end_m"]) < 1e-9
    left_out = bay.get("points_outside_bay", 0) + bay.get("points_not_wall", 0) + bay.get("points_obstacle", 0)
    if whole and left_out == 0:
        return ""
    how = {"detect": "detected: the stretch that is not lining", "range": "grid.bay_start_m..bay_end_m",
           "whole": "the whole scan"}.get(bay["selection"], bay["selection"])
    return html.escape(f"; chainage {bay['start_m']:.2f}..{bay['end_m']:.2f} m of the scan's "
                       f"{bay['scan_start_m']:.2f}..{bay['scan_end_m']:.2f} m ({how}); "
                       f"{left_out:,} points near the design line left out of the grid "
                       f"({bay.get('points_not_wall', 0):,} facing away from the axis: face, floor; "
                       f"{bay.get('points_obstacle', 0):,} in front of the wall: duct)")


def fmt_sig(value: float, sig: int = 3) -> str:
    """``value`` to ``sig`` significant digits in plain notation (no exponent)."""
    if value == 0 or not math.isfinite(value):
        return "0" if value == 0 else str(value)
    digits = max(0, sig - 1 - int(math.floor(math.log10(abs(value)))))
    return f"{value:.{digits}f}"


def fmt_duration(seconds: float) -> str:
    """Seconds as '1 h 02 min 05 s', '14 min 35 s' or '45 s' (to the second)."""
    total = int(round(seconds))
    h, rest = divmod(total, 3600)
    m, s = divmod(rest, 60)
    if h:
        return f"{h} h {m:02d} min {s:02d} s"
    if m:
        return f"{m} min {s:02d} s"
    return f"{s} s"


def fmt_mm(value: float) -> str:
    return f"{value:.0f} mm" if abs(value) >= 10 else f"{value:.1f} mm"


def fmt_pct(part: float, whole: float) -> str:
    if whole <= 0:
        return "-"
    pct = 100.0 * part / whole
    if part < whole and pct >= 99.95:
        return "&gt;99.9 %"
    if 0 < part and pct < 0.05:
        return "&lt;0.1 %"
    return f"{pct:.1f} %"


def _v(key: str, text: str, tag: str = "span") -> str:
    """A figure of the summary; ``data-key`` names it for the test that checks it against report.json."""
    return f'<{tag} data-key="{key}">{text}</{tag}>'


def _volume(key: str, m3: float, length_m: float) -> str:
    return (_v(key, f"{fmt_sig(m3)} m³") + " · " + _v(f"{key}_per_m", f"{fmt_sig(m3 / length_m)} m³/m"))


def _where(regions: list, limit: int = 4) -> str:
    if not regions:
        return ""
    parts = [f"{g['part']}, d {g['d_m'][0]:.2f}–{g['d_m'][1]:.2f} m, s {g['s_m'][0]:.2f}–{g['s_m'][1]:.2f} m "
             f"({g['cells']} cell{'s' if g['cells'] > 1 else ''}, up to {abs(g['worst_mm']):.0f} mm "
             f"{'missing' if g['worst_mm'] > 0 else 'over'})" for g in regions[:limit]]
    more = f"; and {len(regions) - limit} more groups" if len(regions) > limit else ""
    return ": " + "; ".join(parts) + more


def _levels_text(levels: dict) -> str:
    return " · ".join(f"{k}: {v}" for k, v in sorted(((int(k), v) for k, v in levels.items())))


# report.json cycle_time_breakdown_s (the core's CycleTimeBreakdown), in words.
CYCLE_PARTS = (("spraying", "spraying (nozzle on)"), ("turn_arounds", "turn-arounds between passes"),
               ("leads", "lead-ins and lead-outs"), ("transits", "transits between regions"),
               ("stop_and_go", "stop-and-go between passes that are no neighbours"), ("other", "other (nozzle off)"))


def summary_html(report: dict, facts: PageFacts) -> str:
    """The first screen: verdict, key figures (cards and table), thickness classes, cycle time and
    rounds. Every figure comes from report.json or the core's per-cell values (``facts``)."""
    tol = LEVEL0_TOLERANCE_MM
    levels_after = {int(k): v for k, v in report["levels_after"].items()}
    cells = report["cells"]
    n_within = levels_after.get(0, 0)
    n_missing = sum(v for k, v in levels_after.items() if k >= 1)
    n_over = levels_after.get(-1, 0)
    ok = report.get("status", "ok") == "ok"
    done = ok and n_missing == 0
    source = "executed trajectory with the pump's flow" if report.get("deposit_source") == "executed" \
        else "planner's estimate (no trajectory)"
    if done:
        # Executable as far as it was checked: without clearance.enabled nobody looked at the arm
        # against the wall, and the page must not suggest otherwise.
        checked = ("within the joint limits and clear of the wall by its margins" if report.get("clearance")
                   else "within the joint limits; its clearance to the wall was not checked (clearance.enabled)")
        verdict = (f"{_v('verdict', 'Done', 'b')}: after spraying no cell of the bay misses more than {tol:.0f} mm "
                   f"of concrete; the plan is executable as reported, {checked}")
    elif n_missing:
        verdict = (f"{_v('verdict', 'Not done', 'b')}: {n_missing} cells still miss more than {tol:.0f} mm of concrete"
                   f"{_where(facts.missing_regions, 2)}")
    else:
        verdict = f"{_v('verdict', 'Not done', 'b')}: the plan cannot be executed as reported (the problems are listed above)"
    ex = report.get("executed") or None
    length = facts.bay_length_m
    cycle = report.get("cycle_time_s")
    cards = [
        ("Concrete to spray", (_v("sprayed", f"{fmt_sig(ex['sprayed_m3'] if ex else report['sprayed_volume_m3'])} m³")
                               + f"<small>{_v('sprayed_per_m', fmt_sig((ex['sprayed_m3'] if ex else report['sprayed_volume_m3']) / length) + ' m³/m')}"
                               f" of tunnel · {_v('required', fmt_sig(report['required_volume_m3']) + ' m³')} missing"
                               "</small>")),
        ("Rig busy (cycle time)", _v("cycle_time", fmt_duration(cycle)) if cycle is not None
         else _v("cycle_time", "no trajectory")),
        (f"Cells within ±{tol:.0f} mm", _v("cells_within_pct", fmt_pct(n_within, cells))
         + f"<small>{_v('cells_missing', str(n_missing))} missing · {_v('cells_over', str(n_over))} over-filled</small>"),
        ("Residual after spraying", _v("residual_rms", fmt_mm(report["residual_mm"]["rms"])) + "<small>rms TD</small>"),
    ]
    card_html = "".join(f'<div class="card"><div class="label">{label}</div><div class="big">{value}</div></div>'
                        for label, value in cards)

    rows = [
        ("Status", _v("status", html.escape(report.get("status", "ok")))),
        (f"Cells within ±{tol:.0f} mm after spraying",
         f"{_v('cells_within', str(n_within))} of {_v('cells', str(cells))} cells ({_v('cells_within_pct', fmt_pct(n_within, cells))})"),
        (f"Cells missing more than {tol:.0f} mm", _v("cells_missing", str(n_missing)) + _where(facts.missing_regions)),
    ]
    if report.get("holes"):
        rows += [("Holes (grid cells no scan point fell in)",
                  f"{_v('holes', str(report['holes']))} cells, neither graded nor sprayed (a scanner's shadow, "
                  "a gap in the scan): not counted above")]
    rows += [
        (f"Cells over-filled by more than {tol:.0f} mm", _v("cells_over", str(n_over)) + _where(facts.over_regions)),
        (f"Cells within the planner's finish tolerance ±{facts.finish_tolerance_mm:.0f} mm",
         f"{_v('cells_finish', str(facts.cells_within_finish))} of {cells} "
         f"({_v('cells_finish_pct', fmt_pct(facts.cells_within_finish, cells))})"),
        ("Residual TD after spraying", " · ".join(
            f"{name} {_v('residual_' + k, fmt_mm(report['residual_mm'][k]))}"
            for k, name in (("mean", "mean"), ("rms", "rms"), ("min", "min"), ("max", "max")))),
        ("TD before spraying", " · ".join(
            f"{name} {_v('td_before_' + k, fmt_mm(report['td_before_mm'][k]))}"
            for k, name in (("mean", "mean"), ("min", "min"), ("max", "max")))),
        ("Bay length (grid along the axis)", _v("bay_length", f"{length:.2f} m")
         + f" ({round(length / facts.cell_size_m)} cells of {facts.cell_size_m * 100:g} cm)" + _bay_note(report.get("bay"))),
        ("Concrete missing (required)", _volume("required", report["required_volume_m3"], length)),
    ]
    if ex:
        rows += [("Sprayed (pump)", _volume("sprayed", ex["sprayed_m3"], length)),
                 ("Rebound", _volume("rebound", ex["rebound_m3"], length)),
                 ("Landed outside the bay", _volume("outside", ex["outside_m3"], length)),
                 ("On the wall", _volume("on_wall", ex["on_wall_m3"], length))]
    else:
        rows += [("Sprayed (planner's estimate, no trajectory)", _volume("sprayed", report["sprayed_volume_m3"], length))]
    rows += [("Cycle time (whole trajectory)", _v("cycle_time", fmt_duration(cycle)) if cycle is not None
              else "no trajectory"),
             ("Rounds · regions · passes", f"{_v('rounds', str(report['rounds']))} · {_v('regions', str(report['regions']))}"
              f" · {_v('passes', str(report['passes']))}")]
    table = "".join(f"<tr><th>{k}</th><td>{v}</td></tr>" for k, v in rows)

    breakdown = ""
    parts = (report.get("trajectory") or {}).get("cycle_time_breakdown_s") or report.get("cycle_time_breakdown_s")
    if parts and cycle:
        lines = "".join(f"<tr><th>{name}</th><td>{_v('ct_' + key, fmt_duration(parts[key]))}</td>"
                        f"<td>{_v('ct_' + key + '_pct', fmt_pct(parts[key], cycle))}</td></tr>"
                        for key, name in CYCLE_PARTS if key in parts)
        breakdown = (f'<table class="compact" id="cycle-breakdown"><tr><th>cycle time</th><th>time</th><th>share</th></tr>'
                     f"{lines}<tr><th>total</th><td>{_v('cycle_time', fmt_duration(cycle))}</td><td>100 %</td></tr></table>")
        slowed = (report.get("trajectory") or {}).get("slowed_to_joint_limits") or {}
        if slowed.get("added_s", 0) > 0:
            breakdown += (f'<p class="note" id="slowed">Included: {_v("slowed_s", fmt_duration(slowed["added_s"]))} where the '
                          f"timed motion broke a joint limit (up to {slowed['ratio_before']:.2f}x), slowed down to it.</p>")

    round_rows = []
    for r in report.get("rounds_detail", []):
        n = r["round"]
        after = {int(k): v for k, v in r["levels_after"].items()}
        above = sum(v for k, v in after.items() if k >= 1)
        round_rows.append(
            f"<tr><td>{n}</td><td>{html.escape(r['kind'])}</td><td>{r['level']}</td>"
            f"<td>{_v(f'round{n}_regions', str(r['regions']))}</td><td>{_v(f'round{n}_passes', str(r['passes']))}</td>"
            f"<td>{_v(f'round{n}_spray_time', fmt_duration(r['spray_time_s']))}</td>"
            f"<td>{_v(f'round{n}_above', str(above))}</td><td class=\"small\">{_levels_text(r['levels_after'])}</td></tr>")
    rounds = ('<table class="compact" id="rounds"><tr><th>round</th><th>kind</th><th>level</th><th>regions</th>'
              "<th>passes</th><th>spray time (planned)</th><th>cells above level 0 after</th>"
              f"<th>cells per level after (planned)</th></tr>{''.join(round_rows)}</table>") if round_rows else ""
    note = (f"Thickness classes use the core's level 0 band: TD within ±{tol:.0f} mm of the design line "
            f"(level_of_td_mm; the plan is done when no cell is above it). The planner's own finish tolerance "
            f"(planner.finish_tolerance_m = {facts.finish_tolerance_mm:.0f} mm) is its stopping target. "
            f"Values after spraying are of the {source}. m³/m: per metre of tunnel (bay length {length:.2f} m).")
    return f"""<section id="summary">
<div class="verdict {'ok' if done else 'bad'}" id="verdict">{verdict}</div>
<div class="cards">{card_html}</div>
<div class="cols"><div class="col">
<table id="summary-table">{table}</table>
<p class="note">{html.escape(note)}</p>
</div><div class="col" id="class-map-slot">CLASS_MAP</div></div>
<div class="cols"><div class="col"><h3>Where the time goes</h3>{breakdown or '<p>No trajectory: no cycle time.</p>'}</div>
<div class="col"><h3>Rounds</h3>{rounds}</div></div>
</section>"""


def _figure(caption: str, src: str) -> str:
    return (f'<figure><img src="{html.escape(src)}" alt="{html.escape(caption)}" loading="eager">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def write_html(out: Path, report: dict, figures: list[tuple[str, str, str]], facts: PageFacts | None = None,
               title: str = "Shotcrete plan") -> Path:
    """report.html: the status banner, the summary (``facts``: see PageFacts), the 3-D view, the
    figures grouped (``figures``: (group, caption, src) with group "summary", "before", "round N"
    or "after"), then every scalar of report.json in a collapsed table."""
    raw_rows = []
    for key, value in report.items():
        if isinstance(value, (dict, list)) and len(json.dumps(_jsonable(value))) > 200:
            continue
        raw_rows.append(f"<tr><th>{html.escape(str(key))}</th><td>{html.escape(json.dumps(_jsonable(value)))}</td></tr>")
    status = report.get("status", "ok")
    if status == "ok":
        banner = '<p class="ok">status: ok</p>'
    else:  # a plan that is not right says so before any figure
        items = "".join(f"<li>{html.escape(p['message'])} ({html.escape(p['code'])})</li>" for p in report.get("problems", []))
        banner = f'<div class="bad"><b>status: {html.escape(status)}</b>: this plan is not executable as reported<ul>{items}</ul></div>'
    # Where the rig stands when the job moved its base (robot.place_base): the crew parks it there.
    placed = report.get("base_placement") or {}
    if placed.get("moved"):
        pos = ", ".join(f"{v:.3f}" for v in placed["position_m"])
        conf = ", ".join(f"{v:.3f}" for v in placed["configured_m"])
        way = "back" if placed["shift_m"] < 0 else "forward"
        banner += (f'<p class="note" id="base-placement"><b>Rig placement</b>: the arm\'s base stands at ({pos}) m, '
                   f'{abs(placed["shift_m"]):.1f} m {way} along the axis from robot.base_position_m ({conf}) m, '
                   f'where the arm has room to turn every way (report.json base_placement)</p>')
    groups: dict[str, list[str]] = {}
    for group, cap, src in figures:
        groups.setdefault(group, []).append(_figure(cap, src))
    summary = ""
    if facts is not None:
        summary = summary_html(report, facts).replace("CLASS_MAP", "".join(groups.pop("summary", [])))
    sections = []
    if groups.get("before"):
        sections.append(f'<h2>Before spraying</h2><div class="figs">{"".join(groups.pop("before"))}</div>')
    rounds = [g for g in groups if g.startswith("round ")]
    if rounds:
        blocks = "".join(f'<details><summary>{html.escape(g.capitalize())}</summary><div class="figs">{"".join(groups.pop(g))}</div></details>'
                         for g in rounds)
        sections.append(f"<h2>Round by round</h2>{blocks}")
    for g, figs in groups.items():
        sections.append(f'<h2>{"After spraying" if g == "after" else html.escape(g.capitalize())}</h2><div class="figs">{"".join(figs)}</div>')
    view = ""
    if facts is not None and facts.view_html:
        view = f'<section id="view"><h2>3-D view</h2>{facts.view_html}</section>'
    head_script = '<script src="plotly.min.js"></script>' if view else ""
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<meta name="viewport" content="width=device-width, initial-scale=1">
{head_script}
<style>
body{{font-family:system-ui,sans-serif;margin:0 auto;padding:0.6em 1.2em;max-width:1400px;color:#222}}
h1{{font-size:1.4em;margin:0.2em 0}} h2{{font-size:1.2em;margin-top:1.5em;border-bottom:1px solid #ccc}}
h3{{font-size:1em;margin:0.6em 0 0.3em}}
table{{border-collapse:collapse}} th,td{{border:1px solid #ccc;padding:3px 7px;text-align:left;font-size:90%;vertical-align:top}}
th{{background:#f6f6f6;font-weight:600}} .small,small{{font-size:80%;color:#555}}
.ok{{color:#070;margin:0.2em 0}} .bad{{border:2px solid #c00;padding:0.3em 1em;color:#900}}
.verdict{{font-size:1.15em;padding:0.5em 0.8em;border-radius:6px;margin:0.4em 0}}
.verdict.ok{{background:#e5f5e0;border:2px solid #1a9641;color:#114d22}} .verdict.bad{{background:#fde0dd;border:2px solid #d7191c;color:#7a0010}}
.cards{{display:flex;gap:0.8em;flex-wrap:wrap;margin:0.5em 0}}
.card{{flex:1 1 200px;border:1px solid #ccc;border-radius:6px;padding:0.4em 0.8em;background:#fafafa}}
.card .label{{font-size:85%;color:#555}} .card .big{{font-size:1.6em;font-weight:600}} .card small{{display:block;font-weight:400;font-size:55%}}
.cols{{display:flex;gap:1.2em;flex-wrap:wrap;align-items:flex-start}} .col{{flex:1 1 420px;min-width:0}}
#class-map-slot img{{max-height:470px;max-width:100%}} #class-map-slot figure{{margin:0}}
.note{{font-size:80%;color:#555;max-width:60em}} [data-key]{{white-space:nowrap}}
figure{{display:inline-block;margin:0.6em;vertical-align:top}} img{{max-height:650px;max-width:100%}}
figcaption{{font-size:85%;color:#444;max-width:40em}} details{{margin:0.4em 0}} summary{{cursor:pointer;font-weight:600}}
</style></head>
<body><h1>{html.escape(title)}</h1>
{banner}
{summary}
{view}
{''.join(sections)}
<h2>All figures of report.json</h2>
<details id="raw"><summary>report.json, every scalar (the full file: <a href="report.json">report.json</a>; per cell: <a href="cells.csv">cells.csv</a>)</summary>
<table>{''.join(raw_rows)}</table></details>
</body></html>
"""
    path = out / "report.html"
    path.write_text(page)
    return path
