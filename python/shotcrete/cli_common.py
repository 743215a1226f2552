"""What the ``shotcrete`` command modules share: the console, bad input as exit code 2, the config
with --units, JSON on stdout. Imported by the cli* modules only."""
from __future__ import annotations

import json
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console

from .config import load_config
from .io import UNIT_SCALES

console = Console(stderr=True, soft_wrap=True)  # errors on one line, never wrapped

EXIT_BAD_INPUT = 2


@contextmanager
def user_errors():
    """Bad input becomes one red line and exit code 2, never a traceback."""
    try:
        yield
    except (ValueError, FileNotFoundError) as exc:
        console.print(f"[red]error:[/red] {exc}", highlight=False)
        raise typer.Exit(EXIT_BAD_INPUT)
    except RuntimeError as exc:
        console.print(f"[red]failed:[/red] {exc}", highlight=False)
        raise typer.Exit(1)


def cli_config(path: Optional[Path], units: str = "m"):
    """The config of --config (default config/default.yaml), with io.unit_scale from --units."""
    config = load_config(path)
    if units not in UNIT_SCALES:
        raise ValueError(f"--units must be one of {', '.join(UNIT_SCALES)}, got {units!r}")
    if units != "m":
        config.io.unit_scale = UNIT_SCALES[units]
    return config


def print_json(data, **dumps_options) -> None:
    """``data`` as JSON on stdout (the console writes to stderr)."""
    sys.stdout.write(json.dumps(data, **dumps_options) + "\n")


@contextmanager
def progress_reporter(disable: bool = False):
    """A rich progress bar per stage on stderr; yields progress(stage, fraction) for the core's
    ProgressFn (shown unless disabled, e.g. with --json)."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(), console=console,
                  disable=disable) as bar:
        tasks: dict[str, int] = {}

        def progress(stage: str, fraction: float) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(stage, total=1.0)
            bar.update(tasks[stage], completed=fraction)

        yield progress
