"""Do better codes make better policies? The 10-demonstration Meta-World rows with the segmentation start of
2026-12-07 beside the start before it.

    python benchmarks/metaworld_codes_downstream.py    # prints the table, draws figures/metaworld_codes_downstream.png

Reads three files of `benchmarks/metaworld_fewdemo.py` (each row keeps its commands):

- `metaworld_fewdemo.json`: the published rows, made before the start changed (BC with codes, and Directed-Info
  GAIL + L2 from it at 61 PPO iterations, 249,856 env steps);
- `metaworld_fewdemo_oldstart_bc.json`: those BC rows made again with the old start named
  (`--pretrain-args "--vae.init-actions gaussian --vae.init-ridge 1.0"`), which also keep how well the codes segment
  the task's 50 shipped demonstrations against the expert's phases;
- `metaworld_fewdemo_newstart.json`: the same rows with today's defaults (BC and Directed-Info GAIL + L2, 61
  iterations) and their segmentation.

Per task (medians over seeds 0-2): the codes' accuracy old and new, and the success of each method old and new, with
the change over the seeds both have; the figure sets each task's change in accuracy against its change in success.
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "metaworld"
TASKS = ("pick-place", "assembly", "shelf-place", "peg-insert-side", "box-close", "hammer")
METHODS = {"bc": ("bc", None), "digail-l2": ("digail-l2", 61)}
"""column -> (method, iterations) of metaworld_fewdemo.py's rows"""


def _rows(path: Path) -> list[dict[str, Any]]:
    return json.loads(path.read_text())["rows"] if path.is_file() else []


def _median(values: list[float]) -> float | None:
    return statistics.median(values) if values else None


def collect(results: Path = RESULTS) -> dict[str, Any]:
    """Per task: medians and per-seed values of the segmentation accuracy and of each method's success, old and new."""
    old, old_bc = _rows(results / "metaworld_fewdemo.json"), _rows(results / "metaworld_fewdemo_oldstart_bc.json")
    new = _rows(results / "metaworld_fewdemo_newstart.json")

    def pick(rows: list[dict[str, Any]], task: str, method: str, iterations: int | None) -> list[dict[str, Any]]:
        found = [r for r in rows if r["task"] == task and r["method"] == method and r.get("iterations") == iterations]
        return sorted(found, key=lambda r: r["seed"])

    out: dict[str, Any] = {}
    for task in TASKS:
        entry: dict[str, Any] = {}
        for era, bc_rows in (("old", old_bc), ("new", new)):
            accs = [r["segmentation"]["accuracy"] for r in pick(bc_rows, task, "bc", None) if r.get("segmentation")]
            entry[f"accuracy_{era}"] = {"median": _median(accs), "seeds": accs}
        for column, (method, iterations) in METHODS.items():
            by_seed = {}
            for era, rows in (("old", old), ("new", new)):
                found = pick(rows, task, method, iterations)
                by_seed[era] = {r["seed"]: r["success_rate"] for r in found}
                success = [r["success_rate"] for r in found]
                entry[f"{column}_{era}"] = {"median": _median(success), "seeds": success}
            # the change over the seeds both have (a seed still training has no new row yet)
            both = sorted(set(by_seed["old"]) & set(by_seed["new"]))
            change = (_median([by_seed["new"][s] for s in both]) - _median([by_seed["old"][s] for s in both])
                      if both else None)
            entry[f"{column}_change"] = {"value": change, "seeds": both}
        # the old BC rows made again should give the published numbers (the same seeds, the same start); where
        # the code has moved on since, the seeds that differ are told
        again = {r["seed"]: r["success_rate"] for r in pick(old_bc, task, "bc", None)}
        published = {r["seed"]: r["success_rate"] for r in pick(old, task, "bc", None)}
        entry["old_bc_again"] = {str(s): v for s, v in again.items()}
        entry["old_bc_differs"] = {str(s): [published.get(s), v] for s, v in again.items() if published.get(s) != v}
        out[task] = entry
    return out


def _cell(entry: dict[str, Any]) -> str:
    if entry["median"] is None:
        return "-"
    return f"{entry['median']:.2f} ({' / '.join(f'{v:.2f}' for v in entry['seeds'])})"


def _change(entry: dict[str, Any]) -> str:
    if entry["value"] is None:
        return "-"
    seeds = entry["seeds"]
    return f"{entry['value']:+.2f}" + ("" if len(seeds) == 3 else f" (seed{'s' if len(seeds) > 1 else ''} "
                                                                      f"{', '.join(map(str, seeds))})")


def table(data: dict[str, Any]) -> str:
    lines = ["| task | codes' accuracy, old start | new start | BC with codes, old | new | change | "
             "Directed-Info GAIL + L2, old | new | change |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for task, e in data.items():
        lines.append(f"| {task} | {_cell(e['accuracy_old'])} | {_cell(e['accuracy_new'])} | {_cell(e['bc_old'])} | "
                     f"{_cell(e['bc_new'])} | {_change(e['bc_change'])} | "
                     f"{_cell(e['digail-l2_old'])} | {_cell(e['digail-l2_new'])} | {_change(e['digail-l2_change'])} |")
    return "\n".join(lines)


def figure(data: dict[str, Any], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), sharey=True)
    panels = (("bc", "BC with codes"), ("digail-l2", "Directed-Info GAIL + L2, 250k steps"))
    for ax, (column, title) in zip(axes, panels, strict=True):
        for task, e in data.items():
            a0, a1 = e["accuracy_old"]["median"], e["accuracy_new"]["median"]
            change = e[f"{column}_change"]["value"]
            if None in (a0, a1, change):
                continue
            ax.scatter(a1 - a0, change, color="tab:blue")
            ax.annotate(task, (a1 - a0, change), fontsize=8, xytext=(4, 3), textcoords="offset points")
        ax.axhline(0, color="grey", lw=0.6)
        ax.axvline(0, color="grey", lw=0.6)
        ax.set_xlabel("change in the codes' accuracy (new start - old)")
        ax.set_title(title, fontsize=10)
    axes[0].set_ylabel("change in success (median over the seeds both have)")
    fig.suptitle("Meta-World, 10 demonstrations: the segmentation's change against the policy's change", fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, default=RESULTS)
    parser.add_argument("--figure", type=Path, default=HERE / "results" / "figures" / "metaworld_codes_downstream.png")
    args = parser.parse_args(argv)
    data = collect(args.results)
    print(table(data))
    for task, e in data.items():
        for seed, (published, again) in e["old_bc_differs"].items():
            print(f"note: {task} seed {seed}: BC with the old start made again {again}, published {published}")
    figure(data, args.figure)


if __name__ == "__main__":
    main()
