"""`digail report RUN`: figures and one self-contained report.html; `digail report --compare RUN...`: one page
over methods and seeds."""

from __future__ import annotations

import contextlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import tyro

from digail.errors import UserError


@dataclass(frozen=True)
class ReportArgs:
    """Write a run's figures and its self-contained report.html, or (--compare) one page over many runs."""

    runs: Annotated[tuple[Path, ...], tyro.conf.Positional]
    """a run folder; with --compare, several run folders or one sweep folder holding them"""
    compare: bool = False
    """build a methods-by-seeds page (learning curves, table of medians) instead of one run's report"""
    out: Path | None = None
    """output page (default: RUN/report.html; with --compare, compare.html in the sweep folder or the runs' common
    folder)"""
    force: bool = False
    """replace an existing --out page (and, with --compare, the figure beside it), only one digail wrote"""
    figures: bool = True
    """redraw the run's figures from its model and demonstrations first (--no-figures: use those present)"""
    unsmoothed: Path | None = None
    """a VAE run folder trained without the smoothing term, shown beside the run's own segmentation"""


def report_command(args: ReportArgs) -> Path:
    """Write the page; returns its path."""
    from digail.fsio import run_dir_lock
    from digail.viz.report import write_compare_report, write_report

    if not args.runs:
        raise UserError("name a run folder: `digail report RUN` (or several with --compare).")
    missing = [str(r) for r in args.runs if not Path(r).is_dir()]
    if missing:
        raise UserError(f"run folder {missing[0]} does not exist; pass a folder made by `digail run` or "
                        "`digail train`.")
    if args.compare:
        runs = find_runs(args.runs)
        if not runs:
            raise UserError(f"no run folders (with a config.json) in {', '.join(map(str, args.runs))}.")
        folder = Path(args.runs[0])
        sweep = len(args.runs) == 1 and not (folder / "config.json").exists()
        compare = args.out or (folder if sweep else _common_parent(runs)) / "compare.html"
        check_page_path(compare, runs, force=args.force or args.out is None, figure=True)
        page = write_compare_report(runs, compare)
        print(f"compared {len(runs)} runs: {page}")
        return page
    if len(args.runs) != 1:
        raise UserError(f"got {len(args.runs)} run folders; pass one, or add --compare for a comparison page.")
    run = Path(args.runs[0])
    if not (run / "config.json").is_file():
        raise UserError(f"{run} is not a run folder (it has no config.json); pass a folder made by `digail run`, "
                        "`digail train` or `digail pretrain`.")
    own_page = run / "report.html"
    out = None if args.out is None or _same_path(args.out, own_page) else Path(args.out)
    # the run's own page is rewritten on every call; any other --out follows the rule of every output
    check_page_path(own_page if out is None else out, [run], force=args.force or out is None)
    # one writer per run folder: its figures and its page are written into it
    with run_dir_lock(run) if args.figures or out is None else contextlib.nullcontext():
        if args.figures and (run / "model.pt").exists():
            make_figures(run, unsmoothed=args.unsmoothed)
        page = write_report(run, out)
    print(f"report: {page}")
    return page


def check_page_path(out: Path, runs: list[Path], force: bool, figure: bool = False) -> None:
    """Refuse, before anything is drawn, a page path `digail.fsio.check_output` refuses: one of the runs' own
    files (their model, config, checkpoint, dataset) or inside one, a link, a FIFO or a device, a folder, an
    existing file without `force` or one that is not a page digail wrote. With `figure`, the learning-curves
    figure written beside a comparison page is checked the same way."""
    from digail.fsio import check_output
    from digail.viz.figures import is_figure
    from digail.viz.html_page import is_page
    from digail.viz.report import compare_figure

    protected = run_files(runs)
    check_output(Path(out), "file", force, protected=protected, ours=is_page,
                 ours_what="a report page digail wrote", writes="`digail report` writes a page",
                 example="report.html")
    if figure:
        fig = compare_figure(Path(out))
        check_output(fig, "file", force, protected=protected, ours=is_figure, ours_what="a figure digail drew",
                     writes="`digail report --compare` writes a figure beside its page", example=fig.name)


def run_files(runs: list[Path]) -> list[tuple[Path, str]]:
    """What a report never writes over: every file and folder of the runs (their pages aside, which it rewrites)
    and each run's dataset."""
    from digail.commands.common import resolve_ref
    from digail.viz.html_page import is_page

    protected: list[tuple[Path, str]] = []
    for run in map(Path, runs):
        for child in sorted(run.iterdir()):
            if not (child.suffix == ".html" and child.is_file() and not child.is_symlink() and is_page(child)):
                kind = "folder" if child.is_dir() and not child.is_symlink() else "file"
                protected.append((child, f"the run's {kind} {child.name}"))
        demos = resolve_ref(run, _load_json(run / "config.json").get("demos"))
        if demos and Path(demos).exists():
            protected.append((Path(demos), "the run's dataset"))
    return protected


def _same_path(a: Path, b: Path) -> bool:
    import os

    return os.path.realpath(a) == os.path.realpath(b) and not Path(a).is_symlink()


def find_runs(paths: tuple[Path, ...] | list[Path], depth: int = 3) -> list[Path]:
    """Run folders among `paths`: each path holding a config.json, else the run folders found below it, up to
    `depth` levels down (a sweep keeps its runs in SWEEP/<env>/<run>). A run's own sub-folders (its vae/) are not
    runs of their own here."""
    out: list[Path] = []
    for p in map(Path, paths):
        if (p / "config.json").exists():
            out.append(p)
        elif depth > 0 and p.is_dir():
            out += find_runs(sorted(c for c in p.iterdir() if c.is_dir() and not c.name.startswith(".")), depth - 1)
    return out


def _common_parent(runs: list[Path]) -> Path:
    import os

    return Path(os.path.commonpath([str(r.resolve().parent) for r in runs]))


def _demo_codes(run: Path) -> list[np.ndarray] | None:
    path = run / "codes.npz"
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            return [z[k] for k in sorted(z.files)]
    except (OSError, ValueError):  # unreadable, or object arrays that would need pickle: segment again
        return None


def make_figures(run: Path, *, model: Any = None, trajs: Any = None, unsmoothed: Path | None = None,
                 episodes: int = 6) -> list[Path]:
    """Every figure of `run` (viz.run_figures) from its model.pt, its demonstrations (config.json's `demos`) and
    its codes.npz (segmented again when missing); composition from compose.json's schedule.

    `model` and `trajs` skip the loading when the caller holds them (`digail run`).
    """
    from digail.checkpoint import load_model
    from digail.commands.common import run_env_id
    from digail.data.minari_io import load_dataset
    from digail.eval.composition import CodeSchedule, parse_schedule
    from digail.eval.segmentation import segment_many, viterbi
    from digail.viz.run_figures import write_run_figures

    cfg = json.loads((run / "config.json").read_text()) if (run / "config.json").exists() else {}
    meta: dict[str, Any] = {}
    if model is None:
        model, meta = load_model(run / "model.pt")
    env_id = run_env_id(run, meta)
    if trajs is None:
        if not cfg.get("demos"):
            raise UserError(f"{run}/config.json does not name its demonstrations, so its figures cannot be drawn; "
                            "pass --no-figures.")
        trajs = list(load_dataset(cfg["demos"]).trajs)
    codes = _demo_codes(run)
    if codes is None or len(codes) != len(trajs):
        codes = segment_many(model, trajs)
    comp = json.loads((run / "compose.json").read_text()) if (run / "compose.json").exists() else {}
    schedule_text = str(comp.get("schedule") or "")
    schedule = CodeSchedule(parse_schedule(schedule_text, model.codes)) if schedule_text else None
    pair = None
    shown = trajs[:6]
    smoothing = smoothing_pair(run)
    if unsmoothed is not None:
        other, _ = load_model(Path(unsmoothed) / "model.pt" if Path(unsmoothed).is_dir() else Path(unsmoothed))
        pair = (codes[:6], segment_many(other, shown), ("this run (with its smoothing weight)",
                                                          "VAE without smoothing"), "")
    elif smoothing is not None and len(smoothing[0]) == len(trajs):
        pair = smoothing
    elif np.shape(trajs[0].obs)[1:] == (2,):
        pair = (codes[:6], [viterbi(model, t) for t in shown],
                ("causal argmax q (online)", "Viterbi with the prior (offline)"), "")
    paths = write_run_figures(run, model, env_id, [t.obs for t in trajs], codes, schedule=schedule,
                              schedule_text=schedule_text, pair=pair, episodes=episodes)
    return paths


def smoothing_pair(run: Path) -> tuple[list[np.ndarray], list[np.ndarray], tuple[str, str], str] | None:
    """The two segmentations `digail run` keeps when its VAE has a smoothing term: the run's VAE before the polish
    (`viz.report.BEFORE_POLISH`) and the VAE pre-trained without the term (`UNSMOOTHED`), with panel titles naming
    each one's smoothing weight and scores, and the figure's title; None when the run has not both."""
    from digail.viz.report import BEFORE_POLISH, UNSMOOTHED

    folders = (run / BEFORE_POLISH, run / UNSMOOTHED)
    codes = [_demo_codes(f) for f in folders]
    if codes[0] is None or codes[1] is None or len(codes[0]) != len(codes[1]):
        return None
    weights = [(_load_json(run / "vae" / "config.json").get("vae") or {}).get("smoothing_weight"),
               (_load_json(folders[1] / "config.json").get("vae") or {}).get("smoothing_weight", 0.0)]
    titles = []
    for name, folder, weight in zip(("with the smoothing term", "without it"), folders, weights, strict=True):
        seg = _load_json(folder / "segmentation.json")
        scores = [f"{seg['switches_per_episode']:.2f} switches/demo"] if "switches_per_episode" in seg else []
        if "accuracy" in seg:
            scores.insert(0, f"accuracy {100 * seg['accuracy']:.1f}%")
        lam = f" ($\\lambda_s$ = {weight:g})" if isinstance(weight, int | float) else ""
        titles.append(f"{name}{lam}" + (f"\n{', '.join(scores)} over {len(codes[0])} demos" if scores else ""))
    title = ("Segmentation of the same demonstrations by two VAEs: the same settings and seed but for the smoothing "
             "weight\n(both before the polish; causal codes argmax q, positions coloured by code, a star at the start)")
    return codes[0], codes[1], (titles[0], titles[1]), title


def _load_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return {}
    return data if isinstance(data, dict) else {}
