"""What the ``shotcrete`` command modules share: the console, bad input as exit code 2, the config
with --units, JSON on stdout. Imported by the cli* modules only."""
from __future__ import annotations

import json
import os
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.text import Text

from .config import load_config
from .io import UNIT_SCALES

# Errors on one line, never wrapped; text printed verbatim, never read as markup ("[x, y, z]" stays).
console = Console(stderr=True, soft_wrap=True, markup=False)

EXIT_BAD_INPUT = 2
EXIT_NOT_EXECUTABLE = 3  # planned, but the plan is not right (report.json status / problems)


def say(label: str, message: str, style: str) -> None:
    """``label`` in ``style``, then ``message`` exactly as given."""
    console.print(Text.assemble((label, style), " ", message), highlight=False)


def error_line(exc: BaseException) -> str:
    """The one line of an error: OS errors as "file: reason", other messages with their lines joined."""
    if isinstance(exc, OSError) and exc.strerror:
        names = [str(n) for n in (exc.filename, exc.filename2) if n is not None]
        text = f"{' -> '.join(names)}: {exc.strerror}" if names else exc.strerror
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(line.strip() for line in text.splitlines() if line.strip())


@contextmanager
def user_errors():
    """Every error becomes one red line and exit code 2, never a traceback (the CLI's contract;
    SHOTCRETE_TRACEBACK=1 shows the traceback of an unexpected one)."""
    try:
        yield
    except (typer.Exit, typer.Abort, typer.TyperException):  # the CLI's own exits (RuntimeErrors)
        raise
    except (ValueError, OSError, RuntimeError, MemoryError) as exc:
        say("error:", error_line(exc), "red")
        raise typer.Exit(EXIT_BAD_INPUT)
    except Exception as exc:
        if os.environ.get("SHOTCRETE_TRACEBACK"):
            raise
        say("error:", f"internal error ({type(exc).__name__}): {error_line(exc)}", "red")
        raise typer.Exit(EXIT_BAD_INPUT)


def refuse_overwrite(path: Optional[Path], force: bool, option: str) -> None:
    """A single-file output (``option``) is never overwritten without --force (as ``synth``)."""
    if path is not None and (path.exists() or path.is_symlink()) and not force:
        raise ValueError(f"{option} {path} exists; pass --force to overwrite it")


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
