"""Whole-scene plan benchmark (issue 16's target "a whole-scene scan: only the bay's cells graded;
plan equal within 1 % to the bay alone"): the job planned for the arm (`plan_for_arm`, the figures of
report.json via `summarise_job`) on the generator's scenes around the same default bay:

- `bay alone`: the bay as the demo plans it (the reference);
- `face`: the bay and the face at its end (no lining, invert, duct or rig);
- `scene without duct`: 2 m of lining, the invert, the face and the rig's carrier;
- `whole scene`: the same with a 1.2 m ventilation duct hung 0.3 m under the crown over both bays
  (bench_axis's scene: its surface figures are there);
- `whole scene, duct outlet behind the bay`: the duct ending 0.5 m behind the bay's start, as it
  hangs on site (from the lining; the unlined ground is about to be sprayed).

Per case: status and problems (codes), the executed residual (min / max / RMS), levels after, cells
below level 0 and above level 0, required volume, the executed volumes (sprayed, on the wall, landed
outside the bay), cycle time and its ratio to the physical
limit, the arm's clearance (samples below the margins, the least distance per link), obstructed and
leaned cells; and against the bay alone: the required volume, the sprayed volume, the cycle time and
the residual RMS, in per cent. `targets`: whether each scene's plan is within 1 % of the bay alone's
(required volume, sprayed volume, cycle time) and executable, with the measured figures.

    python bench/bench_scene_plan.py --out bench/results [--cases face ...] [--seed 1] [--note TEXT]
        [--set clearance.nozzle_lean_fade_rad_per_m=0.01 --set robot.base_position_m=[0.2,0,-1.2] ...]

`--set` applies to every case (the bay alone too) and is validated as a config file would be; the
scene (`synth.context_*`) and the seed are the cases' and `--seed`'s.

The scenes take 3-9 min each on 2 idle cores (the stages are printed as they start).
Writes <out>/scene_plan.json.
"""
from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

from shotcrete import _core
from shotcrete.config import _bool_keys, check_config_text
from shotcrete.robot import load_robot

CASES = {
    "bay alone": {},
    "face": {"context_enabled": True, "context_previous_bay_m": 0.0, "context_invert_depth_m": 0.0},
    "scene without duct": {"context_enabled": True, "context_rig_length_m": 4.0},
    "whole scene": {"context_enabled": True, "context_rig_length_m": 4.0, "context_duct_diameter_m": 1.2,
                    "context_duct_gap_m": 0.3},
    "whole scene, duct outlet behind the bay": {"context_enabled": True, "context_rig_length_m": 4.0,
                                                "context_duct_diameter_m": 1.2, "context_duct_gap_m": 0.3,
                                                "context_duct_outlet_d_m": -0.5},
}


def config_with(settings: list[str]):
    """The default config with `section.key=value` settings, read as a config file holding them
    (the package's checks and the core's reader: types, ranges, unknown keys; lists as [a, b, c])."""
    sections: dict[str, list[str]] = {}
    for text in settings:
        key, _, value = text.partition("=")
        section, _, name = key.partition(".")
        if not (section and name and value.strip()):
            raise SystemExit(f"--set {text!r}: expected section.key=value")
        if section == "synth" and (name == "seed" or name.startswith("context_")):
            raise SystemExit(f"--set {text!r}: the cases set the scene and --seed the seed")
        if key in _bool_keys() and value.strip() not in ("true", "false"):
            raise SystemExit(f"--set {text!r}: expected true or false")
        sections.setdefault(section, []).append(f"  {name}: {value}\n")
    yaml_text = "".join(f"{section}:\n" + "".join(lines) for section, lines in sections.items())
    try:
        check_config_text(yaml_text.encode(), Path("--set"))
        return _core.Config.from_yaml(yaml_text)
    except ValueError as e:
        raise SystemExit(f"--set: {e}") from None


def _round(x, digits: int):
    return None if x is None else round(x, digits)


def plan_case(name: str, base_cfg, seed: int) -> dict:
    cfg = base_cfg.copy()
    cfg.synth.seed = seed
    for key, value in CASES[name].items():
        setattr(cfg.synth, key, value)
    cloud = _core.make_synthetic_bay(cfg.synth).sample_scan(cfg.grid.cell_size_m)
    t0 = time.perf_counter()
    last = [""]

    def progress(stage: str, fraction: float) -> None:
        if stage != last[0]:
            last[0] = stage
            print(f"  [{name}] {time.perf_counter() - t0:7.1f} s  {stage}", flush=True)

    surface = _core.build_surface(cloud, cfg)
    robot = load_robot(cfg)
    arm = _core.plan_for_arm(surface, cfg, robot, progress)
    placement = arm.base_placement
    s = _core.summarise_job(surface, arm, robot, cfg, points_in=len(cloud)).to_dict()
    seconds = time.perf_counter() - t0
    levels = {int(k): int(v) for k, v in s["levels_after"].items()}
    res = s["residual_mm"]
    clear = s.get("clearance") or {}
    ob = s.get("obstructed") or {}
    ex = s.get("executed") or {}
    tr = s.get("trajectory") or {}
    return {
        "case": name, "seed": seed, "scan_points": len(cloud), "cells": s["cells"],
        "status": s["status"], "problems": [p["code"] for p in s["problems"]],
        "residual_mm": {k: round(res[k], 2) for k in ("min", "max", "rms")},
        "planned_residual_rms_mm": _round(s["planned_residual_mm"]["rms"], 2),
        "planned_vs_executed_rms_mm": _round((s.get("planned_vs_executed_mm") or {}).get("rms"), 2),
        "levels_after": levels, "cells_below_level_0": sum(v for k, v in levels.items() if k < 0),
        "cells_above_level_0": sum(v for k, v in levels.items() if k > 0),
        "unreachable_cells": s["unreachable_cells"], "speed_capped": s["speed_capped"],
        "required_volume_m3": round(s["required_volume_m3"], 4), "sprayed_volume_m3": _round(ex.get("sprayed_m3"), 4),
        "on_wall_m3": _round(ex.get("on_wall_m3"), 4), "outside_bay_m3": _round(ex.get("outside_m3"), 4),
        "cycle_time_s": _round(s["cycle_time_s"], 1), "cycle_time_ratio": _round(s["cycle_time_ratio"], 3),
        "cycle_time_breakdown_s": {k: round(v, 1) for k, v in s["cycle_time_breakdown_s"].items()},
        "joint_limit_ratios": {"velocity": _round(tr.get("max_velocity_ratio"), 3),
                               "acceleration": _round(tr.get("max_acceleration_ratio"), 3)},
        # summed over the links and the link pairs (a sample counts once for each link below its margin)
        "clearance_link_samples_below_margin": clear.get("samples_below_margin"),
        "clearance_moving_samples_below_margin": clear.get("moving_samples_below_margin"),
        "clearance_samples": clear.get("samples"),
        "clearance_least_m": {l["link"]: _round(l["min_m"], 3) for l in clear.get("links", [])},
        "obstructed_cells": ob.get("cells", 0), "leaned_cells": ob.get("leaned_cells", 0),
        "max_lean_deg": round(ob.get("max_lean_deg", 0.0), 1),
        "base_shift_m": round(placement.shift_m, 2), "base_room_m": round(placement.room_m, 3),
        "base_configured_room_m": round(placement.configured_room_m, 3), "base_place_found": placement.found,
        "wall_s": round(seconds, 1),
    }


def relative(row: dict, ref: dict) -> dict:
    pct = lambda a, b: round(100.0 * (a / b - 1.0), 2) if a is not None and b else None  # noqa: E731
    return {"required_volume_pct": pct(row["required_volume_m3"], ref["required_volume_m3"]),
            "sprayed_volume_pct": pct(row["sprayed_volume_m3"], ref["sprayed_volume_m3"]),
            "cycle_time_pct": pct(row["cycle_time_s"], ref["cycle_time_s"]),
            "residual_rms_pct": pct(row["residual_mm"]["rms"], ref["residual_mm"]["rms"])}


def targets(rows: list[dict]) -> list[dict]:
    out = []
    for r in rows:
        if "vs_bay_alone" not in r:
            continue
        v = r["vs_bay_alone"]
        within = all(v[k] is not None and abs(v[k]) <= 1.0 for k in ("required_volume_pct", "sprayed_volume_pct", "cycle_time_pct"))
        out.append({"target": f"{r['case']}: plan within 1 % of the bay alone's (required and sprayed volume, "
                              "cycle time) and executable",
                    "measured": {**v, "status": r["status"], "problems": r["problems"]},
                    "met": bool(within and r["status"] == "ok")})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("bench/results"))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    ap.add_argument("--note", default="", help="what the run was measured on (written with the results)")
    ap.add_argument("--set", dest="settings", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="a config value for every case (repeatable)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    cfg = config_with(args.settings)
    cases = list(dict.fromkeys(["bay alone", *args.cases]))  # the reference first, always
    rows = []
    for name in cases:
        print(f"=== {name}", flush=True)
        row = plan_case(name, cfg, args.seed)
        if name != "bay alone":
            row["vs_bay_alone"] = relative(row, rows[0])
        rows.append(row)
        print(json.dumps(row), flush=True)
    result = {"machine": platform.machine(), "note": args.note, "settings": args.settings, "cases": rows, "targets": targets(rows)}
    (args.out / "scene_plan.json").write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result["targets"], indent=1))


if __name__ == "__main__":
    main()
