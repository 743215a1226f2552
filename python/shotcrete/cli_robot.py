"""``shotcrete robot``: the manipulator model, IK benchmark and reachability map (shotcrete.robot)."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .cli_common import cli_config, console, print_json, refuse_overwrite, user_errors
from .robot import ik_bench, load_robot, reach, reach_figure, robot_summary

robot_app = typer.Typer(add_completion=False, no_args_is_help=True,
                        help="The 8-DOF spraying manipulator: model, IK benchmark, reachability.")


@robot_app.command("info")
def info(config: Optional[Path] = typer.Option(None, help="YAML config file"),
         as_json: bool = typer.Option(False, "--json", help="print JSON")):
    """Joints, limits and reach of the manipulator."""
    with user_errors():
        summary = robot_summary(load_robot(cli_config(config)))
        if as_json:
            print_json(summary, indent=2)
            return
        console.print(f"URDF {summary['urdf']}: {summary['dof']} joints, reach bound {summary['max_reach_m']:.2f} m")
        for j in summary["joints"]:
            console.print(f"  {j['name']:<15} {j['type']:<9} [{j['lower']:+.2f}, {j['upper']:+.2f}] {j['unit']}  "
                          f"v {j['velocity']:.2f}  a {j['acceleration']:.2f}", highlight=False)


@robot_app.command("ik-bench")
def ik_bench_cmd(samples: int = typer.Option(1000, "--samples", help="random reachable poses"),
                 seed: int = typer.Option(1, help="random seed"),
                 config: Optional[Path] = typer.Option(None, help="YAML config file"),
                 as_json: bool = typer.Option(False, "--json", help="print JSON")):
    """Solve rate and time per solve: ours (5-DOF DLS) vs plain KDL NR_JL."""
    with user_errors():
        if samples < 1:
            raise ValueError("--samples must be >= 1")
        if seed < 0:
            raise ValueError("--seed must be >= 0")
        result = ik_bench(cli_config(config), samples, seed)
        if as_json:
            print_json(result, indent=2)
            return
        for key in ("ours_5dof_neutral_seed", "ours_5dof_random_seed", "ours_5dof_no_restarts", "kdl_nr_jl_6dof"):
            r = result[key]
            console.print(f"{key:<24} solved {100 * r['solve_rate']:6.2f} %  median {r['median_ms']:.3f} ms  "
                          f"mean {r['mean_ms']:.3f} ms", highlight=False)
        console.print(f"limit violations {result['limit_violations']}, tolerance misses {result['tolerance_misses']}")


@robot_app.command("reach")
def reach_cmd(radius_m: Optional[float] = typer.Option(None, "--radius-m", help="wall radius; default 5, 5.6, 6.5, 8"),
              standoff_m: float = typer.Option(1.0, "--standoff-m", help="nozzle standoff [m]"),
              bay_length_m: float = typer.Option(1.2, "--bay-length-m", help="bay length along the axis [m]"),
              n_theta: int = typer.Option(61, help="samples over theta in [0, pi]"),
              n_d: int = typer.Option(13, help="samples along the bay"),
              figure: Optional[Path] = typer.Option(None, "--figure", help="write the map as PNG"),
              force: bool = typer.Option(False, "--force", help="overwrite an existing figure file"),
              config: Optional[Path] = typer.Option(None, help="YAML config file"),
              as_json: bool = typer.Option(False, "--json", help="print JSON")):
    """Reachability of a half-cylinder bay with the nozzle normal to the wall, carrier fixed."""
    with user_errors():
        refuse_overwrite(figure, force, "--figure")
        cfg = cli_config(config)
        radii = [radius_m] if radius_m is not None else [5.0, 5.6, 6.5, 8.0]
        summaries, maps = [], []
        for r in radii:
            s, m = reach(cfg, r, standoff_m, bay_length_m, n_theta, n_d)
            summaries.append(s)
            maps.append(m)
        if figure is not None:
            reach_figure(maps, figure)
        if as_json:
            print_json({"radii": summaries}, indent=2)
            return
        for s in summaries:
            console.print(f"R = {s['radius_m']:g} m: reached {s['reached']}/{s['total']} "
                          f"({100 * s['fraction']:.1f} %), worst joint-limit margin "
                          f"{(s['min_limit_margin'] or 0.0):.3f} of range",
                          highlight=False)
        if figure is not None:
            console.print(f"figure: {figure}")


def register(app: typer.Typer) -> None:
    app.add_typer(robot_app, name="robot")
