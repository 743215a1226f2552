"""report.json and report.html for a job directory."""
from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

MARKER = ".shotcrete-output"


def prepare_out_dir(out: Path, inputs: list[Path] = ()) -> Path:
    """Create ``out``; refuse a non-empty directory we did not write, and outputs over an input."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"output path {out} exists and is not a directory")
    if out.is_dir() and any(out.iterdir()) and not (out / MARKER).exists():
        raise ValueError(f"output directory {out} is not empty and was not written by shotcrete; "
                         "choose another --out so nothing of yours is overwritten")
    for p in inputs:
        if Path(p).resolve().parent == out.resolve():
            raise ValueError(f"input {p} lies in the output directory {out}; choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    (out / "figures").mkdir(exist_ok=True)
    (out / MARKER).write_text("written by shotcrete-planner; files here may be replaced by the next run\n")
    return out


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


def write_html(out: Path, report: dict, figures: list[tuple[str, str]], title: str = "Shotcrete plan") -> Path:
    """A self-contained page: key figures as a table, then each figure with its caption."""
    rows = []
    for key, value in report.items():
        if isinstance(value, (dict, list)) and len(json.dumps(_jsonable(value))) > 200:
            continue
        rows.append(f"<tr><th>{html.escape(str(key))}</th><td>{html.escape(json.dumps(_jsonable(value)))}</td></tr>")
    figs = "\n".join(
        f'<figure><img src="{html.escape(src)}" alt="{html.escape(cap)}"><figcaption>{html.escape(cap)}</figcaption></figure>'
        for cap, src in figures)
    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;margin:2em;max-width:1200px}} table{{border-collapse:collapse}}
th,td{{border:1px solid #ccc;padding:4px 8px;text-align:left;font-size:90%}} figure{{display:inline-block;margin:1em}}
img{{max-height:650px}}</style></head>
<body><h1>{html.escape(title)}</h1>
<p>Full numbers: <a href="report.json">report.json</a>.</p>
<table>{''.join(rows)}</table>
{figs}
</body></html>
"""
    path = out / "report.html"
    path.write_text(page)
    return path
