"""The HTML of the reports (`digail.viz.report`): numbers formatted for people, tables of metrics, images embedded
as data URIs and the page around them with its inline style sheet. The report module gathers what a run folder
holds and decides what each page says.
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

# key -> (label, kind); kind: "pct" (a rate or share shown in %), "num" (3 significant digits), "int",
# "x" (a ratio shown as "1.23 x"), "s" (seconds), or a unit string appended to a number.
METRICS: dict[str, tuple[str, str]] = {
    "mean_return": ("mean return", "per episode"),
    "std_return": ("return standard deviation", "per episode"),
    "normalized_return": ("normalised return (agent / expert)", "x"),
    "mean_length": ("mean episode length", "steps"),
    "success_rate": ("success rate", "pct"),
    "path_length_ratio": ("path length / shortest path (successful episodes)", "x"),
    "order_correct_rate": ("circles drawn in the demonstrated order", "pct"),
    "order_reversed_rate": ("circles drawn in the reversed order", "pct"),
    "radius_error": ("radius error (relative to the radius, capped at 100%)", "pct"),
    "radius_error_median": ("radius error, median", "pct"),
    "closure_error": ("closure error (relative to the radius, capped at 100%)", "pct"),
    "closure_error_median": ("closure error, median", "pct"),
    "episodes": ("episodes", "int"),
    "accuracy": ("accuracy after matching codes to labels", "pct"),
    "nmi": ("normalised mutual information (0 to 1)", "num"),
    "boundary_precision": ("boundary precision", "pct"),
    "boundary_recall": ("boundary recall", "pct"),
    "boundary_f1": ("boundary F1", "pct"),
    "boundary_tolerance": ("boundary tolerance", "steps"),
    "switches_per_episode": ("code switches per episode", "num"),
    "true_switches_per_episode": ("oracle switches per episode", "num"),
    "steps": ("steps scored", "int"),
    "schedule_length": ("schedule length", "steps"),
    "order_completed_rate": ("episodes whose code order ran to its last code", "pct"),
    "hold": ("steps in a row q must leave a code before the next takes over", "int"),
    "codes": ("codes K", "int"),
}

STYLE = """
:root{color-scheme:light}
body{font:16px/1.5 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0 auto;max-width:64rem;
padding:0 1rem 3rem;color:#1b1b1b;background:#fff}
h1{font-size:1.5rem;margin:1.2rem 0 .4rem}h2{font-size:1.2rem;margin-top:2rem;border-bottom:1px solid #ddd}
h3{font-size:1rem;margin:1.2rem 0 .3rem}
.headline{background:#f3f6fb;border-left:4px solid #2a6ebb;padding:.6rem 1rem;margin:1rem 0}
.headline p{margin:.3rem 0}.meaning{font-weight:600}
.scroll{overflow-x:auto;-webkit-overflow-scrolling:touch}
table{border-collapse:collapse;margin:.4rem 0;font-size:.95rem}
th,td{border:1px solid #d6d6d6;padding:.25rem .6rem;text-align:left;vertical-align:top}
td.n{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}th{background:#f4f4f4}
figure{margin:1rem 0}img{max-width:100%;height:auto;display:block;border:1px solid #eee}
figcaption{font-size:.9rem;color:#555}code,pre{font-family:ui-monospace,Menlo,Consolas,monospace;font-size:.9rem}
pre{white-space:pre-wrap;word-break:break-all;background:#f6f6f6;padding:.5rem}
details{margin:.5rem 0}summary{cursor:pointer;font-weight:600}
@media (max-width:40rem){body{font-size:15px;padding:0 .6rem 2rem}.headline{padding:.4rem .6rem}
th,td{padding:.2rem .35rem}table{font-size:.88rem}}
"""


# ------------------------------------------------------------------------------------------ formatting
def fmt(value: Any, kind: str = "num") -> str:
    """A number for people: `pct` as a percentage, `x` as a ratio, `int`, `s` as a duration, else 3
    significant digits followed by `kind` as the unit. Non-finite numbers read 'not defined'."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if not isinstance(value, int | float):
        return str(value)
    v = float(value)
    if not math.isfinite(v):
        return "not defined" if math.isnan(v) else ("∞" if v > 0 else "−∞")
    if kind == "int":
        return f"{round(v):,}"
    if kind == "pct":
        return f"{100 * v:.1f}%"
    if kind == "x":
        return f"{v:.3g} ×"
    if kind == "s":
        return f"{v:.1f} s" if v < 120 else f"{int(v // 60)} min {int(round(v % 60))} s"
    if abs(v) < 5e-4:
        text = "0"  # rounding noise (e.g. the scripted expert's -7e-08) reads as what it is
    elif abs(v) >= 1000:
        text = f"{v:,.0f}"
    else:
        text = f"{v:.3g}"
    return text if kind == "num" else f"{text} {kind}"


def _file_size(path: Path) -> str:
    size = path.stat().st_size
    return f"{fmt(size / 1e6)} MB" if size >= 1e6 else f"{max(1, round(size / 1e3))} kB"


def _esc(x: Any) -> str:
    return html.escape(str(x))


def _label(key: str) -> tuple[str, str]:
    return METRICS.get(key, (key.replace("_", " "), "num"))


def _table(header: Sequence[str], rows: Iterable[Sequence[str]], numeric_from: int = 1) -> str:
    """An HTML table of already formatted strings (cells from column `numeric_from` on are right-aligned)."""
    body = "".join("<tr>" + "".join(f"<td class='n'>{_esc(c)}</td>" if i >= numeric_from else f"<td>{_esc(c)}</td>"
                                    for i, c in enumerate(r)) + "</tr>" for r in rows)
    if not body:
        return ""
    head = "".join(f"<th>{_esc(h)}</th>" for h in header)
    return f"<div class='scroll'><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>"


def metric_rows(columns: Sequence[Mapping[str, Any] | None], keys: Iterable[str] | None = None) -> list[list[str]]:
    """Rows `label, column 1, column 2, ...` for every scalar key present (and not None) in some column."""
    cols = [c or {} for c in columns]
    if keys is None:
        seen: dict[str, None] = {}
        for c in cols:
            for k, v in c.items():
                if isinstance(v, int | float) and not isinstance(v, bool) or isinstance(v, bool):
                    seen.setdefault(k)
        keys = [k for k in METRICS if k in seen] + [k for k in seen if k not in METRICS]
    rows = []
    for k in keys:
        if all(c.get(k) is None for c in cols):
            continue
        label, kind = _label(k)
        rows.append([label] + [fmt(c[k], kind) if c.get(k) is not None else "–" for c in cols])
    return rows


def _flatten(data: Mapping[str, Any], prefix: str = "") -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    for k, v in data.items():
        name = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out += _flatten(v, name + ".")
        elif v is None:
            continue
        elif isinstance(v, list | tuple):
            sep = " × " if all(isinstance(x, int) for x in v) else ", "
            out.append((name, sep.join(map(str, v))))
        else:
            out.append((name, fmt(v)))
    return out


def _img(path: Path, alt: str) -> str:
    mime = "image/gif" if path.suffix == ".gif" else "image/png"
    data = base64.b64encode(path.read_bytes()).decode()
    return f"<img src='data:{mime};base64,{data}' alt='{_esc(alt)}' loading='eager'>"


PAGE_HEAD = ("<!doctype html><html lang='en'><head><meta charset='utf-8'>"
             "<meta name='viewport' content='width=device-width,initial-scale=1'><title>")
"""how every page digail writes begins; its title follows and starts with "digail" (`is_page`)"""


def _page(title: str, body: str) -> str:
    return f"{PAGE_HEAD}{_esc(title)}</title><style>{STYLE}</style></head><body>{body}</body></html>"


def is_page(path: Path) -> bool:
    """Whether the regular file `path` is a page digail wrote (a report or a comparison), which `digail report
    --force` may replace."""
    head = (PAGE_HEAD + "digail").encode()
    try:
        with open(path, "rb") as f:
            return f.read(len(head)) == head
    except OSError:
        return False
