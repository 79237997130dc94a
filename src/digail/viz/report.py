"""A single-file HTML report of a run folder: headline numbers, segmentation scores and every figure."""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path
from typing import Any


def _load(path: Path) -> dict[str, Any] | None:
    return json.loads(path.read_text()) if path.exists() else None


def _table(title: str, data: dict[str, Any] | None) -> str:
    if not data:
        return ""
    rows = "".join(
        f"<tr><td>{html.escape(str(k))}</td><td>{v:.4g}</td></tr>" if isinstance(v, float)
        else f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(str(v))}</td></tr>"
        for k, v in data.items() if not isinstance(v, dict | list)
    )
    return f"<h2>{html.escape(title)}</h2><table>{rows}</table>"


def write_report(run_dir: Path) -> Path:
    """Write RUN/report.html from the JSON results and PNG figures present in the run folder."""
    run_dir = Path(run_dir)
    cfg = _load(run_dir / "config.json") or {}
    parts = [f"<h1>digail run: {html.escape(run_dir.name)}</h1>",
             f"<p>env <b>{html.escape(str(cfg.get('env_id')))}</b>, method <b>{html.escape(str(cfg.get('method')))}"
             f"</b>, seed {html.escape(str(cfg.get('seed')))}, demonstrations {html.escape(str(cfg.get('demos')))}</p>"]
    parts.append(_table("Evaluation (closed-loop macro-policy)", _load(run_dir / "eval.json")))
    ev = _load(run_dir / "eval.json") or {}
    parts.append(_table("Expert, measured the same way", ev.get("expert")))
    parts.append(_table("Segmentation of the demonstrations", _load(run_dir / "segmentation.json")))
    parts.append(_table("Composition", _load(run_dir / "compose.json")))
    parts.append(_table("Timings (s)", _load(run_dir / "timings.json")))
    for png in sorted((run_dir / "figures").glob("*.png")) if (run_dir / "figures").exists() else []:
        data = base64.b64encode(png.read_bytes()).decode()
        parts.append(f"<h3>{html.escape(png.stem)}</h3><img src='data:image/png;base64,{data}'/>")
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto}table{border-collapse:collapse}"
             "td{border:1px solid #ccc;padding:2px 8px}img{max-width:100%}")
    out = run_dir / "report.html"
    out.write_text(f"<!doctype html><html><head><meta charset='utf-8'><style>{style}</style>"
                   f"<title>digail {html.escape(run_dir.name)}</title></head><body>{''.join(parts)}</body></html>")
    return out
