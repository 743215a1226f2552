"""report.json and report.html for a job directory."""
from __future__ import annotations

import hashlib
import html
import json
from pathlib import Path
from typing import Any

import numpy as np


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


def write_html(out: Path, report: dict, figures: list[tuple[str, str]], title: str = "Shotcrete plan") -> Path:
    """A self-contained page: key figures as a table, then each figure with its caption."""
    rows = []
    for key, value in report.items():
        if isinstance(value, (dict, list)) and len(json.dumps(_jsonable(value))) > 200:
            continue
        rows.append(f"<tr><th>{html.escape(str(key))}</th><td>{html.escape(json.dumps(_jsonable(value)))}</td></tr>")
    status = report.get("status", "ok")
    if status == "ok":
        banner = '<p class="ok">status: ok</p>'
    else:  # a plan that is not right says so before any figure
        items = "".join(f"<li>{html.escape(p['message'])} ({html.escape(p['code'])})</li>" for p in report.get("problems", []))
        banner = f'<div class="bad"><b>status: {html.escape(status)}</b>: this plan is not executable as reported<ul>{items}</ul></div>'
    figs = "\n".join(
        f'<figure><img src="{html.escape(src)}" alt="{html.escape(cap)}"><figcaption>{html.escape(cap)}</figcaption></figure>'
        for cap, src in figures)
    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:sans-serif;margin:2em;max-width:1200px}} table{{border-collapse:collapse}}
th,td{{border:1px solid #ccc;padding:4px 8px;text-align:left;font-size:90%}} figure{{display:inline-block;margin:1em}}
img{{max-height:650px}} .ok{{color:#070}} .bad{{border:2px solid #c00;padding:0.5em 1em;color:#900}}</style></head>
<body><h1>{html.escape(title)}</h1>
{banner}
<p>Full numbers: <a href="report.json">report.json</a>.</p>
<table>{''.join(rows)}</table>
{figs}
</body></html>
"""
    path = out / "report.html"
    path.write_text(page)
    return path
