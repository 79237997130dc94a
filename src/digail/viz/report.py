"""Self-contained HTML reports: one page per run folder, one page comparing methods over seeds.

A page is a single file: figures and the GIF are embedded as base64 data URIs, the style sheet is inline, there
is no JavaScript and nothing is fetched, so it opens from a phone's downloads as well as from a laptop. It reads
only the run folder (`config.json`, `eval.json`, `segmentation.json`, `compose.json`, `timings.json`,
`metrics.csv`, `figures/*.png`, `videos/*`); numbers are rounded and named with their units, and an entry whose
value is undefined (`None` in JSON) is left out rather than printed.

`write_report(RUN)` opens with a headline (what was run, the numbers that matter next to the expert's and, where
the paper reports one, the paper's, and one sentence on what they mean) before the details.
`write_compare_report(RUNS, OUT)` groups runs by method, draws the multi-seed learning curves and tables the
medians.
"""

from __future__ import annotations

import json
import math
import os
import statistics
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from digail.envs.registry import env_spec
from digail.fsio import atomic_write_bytes
from digail.viz.html_page import _esc, _file_size, _flatten, _img, _label, _page, _table, fmt, metric_rows


def env_name(env_id: str) -> str:
    """What a report calls an environment: its registry entry's name, else its id."""
    spec = env_spec(env_id)
    return spec.name if spec is not None and spec.name else env_id


def paper_return(env_id: str) -> tuple[float, float] | None:
    """The paper's Directed-Info GAIL mean return ± std for an environment (its registry entry's), if any."""
    spec = env_spec(env_id)
    return spec.paper_return if spec is not None else None

METHOD_NAMES = {"digail": "Directed-Info GAIL", "gail": "GAIL", "vae": "VAE behaviour cloning"}

TASK_KEYS = ("success_rate", "order_correct_rate", "order_reversed_rate", "path_length_ratio", "radius_error")


def _composition_name(comp: Mapping[str, Any]) -> str:
    """'order 1,0' for a closed-loop composition (`digail compose --order`), else 'schedule 1:60,0:60'."""
    if isinstance(comp.get("order"), list):
        return "order " + ",".join(str(c) for c in comp["order"])
    return f"schedule {comp.get('schedule', '')}"


def _load(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return {}
    return data if isinstance(data, dict) else {}


# ------------------------------------------------------------------------------------------ run report
BEFORE_POLISH = "vae/before_polish"
"""Where `digail run` keeps its VAE's own segmentation before the polish refits q to it."""
UNSMOOTHED = "vae_unsmoothed"
"""Where `digail run` keeps the VAE pre-trained without the smoothing term (`RunArgs.smoothing_pair`)."""
TIMING_LABELS = {
    "demos_s": "demonstrations (loaded or recorded)",
    "pretrain_s": "VAE pre-training and polish",
    "pretrain_unsmoothed_s": "VAE without the smoothing term (a second process, beside the training)",
    "train_s": "Directed-Info GAIL training",
    "evaluate_s": "closed-loop evaluation",
    "segment_compose_s": "segmentation and composition",
    "wait_unsmoothed_s": "waiting for the VAE without the smoothing term",
    "figures_video_s": "figures and video",
}
"""Names of the stages in timings.json."""
SMOOTHING_KEYS = ("accuracy", "nmi", "boundary_f1", "switches_per_episode", "true_switches_per_episode")
FIGURE_CAPTIONS = {
    "four_rooms_codes": "Four Rooms (paper Figure 3): the most likely action of each code's sub-task policy in every "
                        "free cell, the apple (red) fixed.",
    "four_rooms_paths": "Paths on the grid coloured by the active code; a star marks the start, red the apple.",
    "generated": "Closed-loop rollouts of the hierarchical policy, coloured by code (left) and by time (right).",
    "compose": "Composition: the sub-task policies run in an order of the user's (a closed-loop code order or a fixed "
               "code schedule) instead of the macro-policy's.",
    "segmentation_pair": "Two segmentations of the same demonstrations side by side, each column titled with what "
                         "made it (on Circle-World: the VAE with and without the smoothing term): positions coloured "
                         "by code above the codes against time.",
    "segmentation": "Segmentation of the demonstrations: codes per step, above the oracle labels where the "
                    "environment has them (codes then take the colour of their matched label).",
    "codes_time": "Codes against time: demonstrations (decoded by q) and closed-loop rollouts.",
    "k_curve": "--codes auto: the held-out description length of each number of codes K (lower is better), the "
               "chosen K marked.",
    "pca_codes": "States projected on their first two principal components, coloured by code.",
    "pendulum_code_map": "Pendulum: angle against angular velocity, coloured by the active code.",
    "learning_curves": "Learning curves against environment steps.",
}
FIGURE_ORDER = list(FIGURE_CAPTIONS)


def run_command(cfg: Mapping[str, Any]) -> str:
    """The command that made a run: `command` in config.json, else rebuilt from its settings."""
    if cfg.get("command"):
        return str(cfg["command"])
    env, seed = cfg.get("env_id", "ENV"), cfg.get("seed", 0)
    preset = f" --preset {cfg['preset']}" if cfg.get("preset") else ""
    if cfg.get("pipeline"):
        return f"digail run {env}{preset} --seed {seed}"
    if cfg.get("kind") == "vae":
        return f"digail pretrain --demos {cfg.get('demos', 'DEMOS')} --seed {seed}"
    return f"digail train --env {env} --demos {cfg.get('demos', 'DEMOS')} --method {cfg.get('method', 'digail')} " \
           f"--seed {seed}"


def _task_score(ev: Mapping[str, Any]) -> tuple[str, float, float | None] | None:
    """The env's main task score of the agent and the expert: (key, agent, expert)."""
    expert = ev.get("expert") or {}
    for key in ("order_correct_rate", "success_rate"):
        if isinstance(ev.get(key), int | float):
            return key, float(ev[key]), expert.get(key)
    return None


def meaning(ev: Mapping[str, Any], cfg: Mapping[str, Any]) -> str:
    """One sentence on what the headline numbers mean."""
    if not ev:
        return "This run has no evaluation yet (eval.json is missing); `digail evaluate RUN` makes one."
    score = _task_score(ev)
    expert_return = (ev.get("expert") or {}).get("mean_return")
    ratio: float | None = None
    what = ""
    if score is not None and score[2]:
        ratio = score[1] / float(score[2])
        what = f"{_label(score[0])[0]} at {fmt(score[1], 'pct')} against the expert's {fmt(score[2], 'pct')}"
    elif isinstance(ev.get("mean_return"), int | float) and isinstance(expert_return, int | float) \
            and abs(expert_return) > 1e-6:
        agent, exp = float(ev["mean_return"]), float(expert_return)
        # how close to the expert, 1 = as good, whatever the sign of the rewards: with negative returns (costs)
        # agent / expert grows as the agent gets worse, so the ratio is inverted there
        ratio = agent / exp if exp > 0 else (exp / agent if agent < 0 else 1.0)
        what = f"a return of {fmt(agent)} against the expert's {fmt(exp)} per episode"
    small = cfg.get("preset") == "smoke"
    if ratio is None:
        sentence = "There is no expert score to compare with, so judge the run by the figures below."
    elif ratio >= 0.9:
        sentence = f"The learned hierarchical policy does the task about as well as the expert ({what})."
    elif ratio >= 0.5:
        sentence = f"The policy has learned much of the task but not all of it ({what})."
    else:
        sentence = f"The policy has not learned the task ({what})."
    if small:
        sentence += " This is a smoke-test run (a few iterations), which checks the plumbing, not the method."
    return sentence


def headline(run_dir: Path) -> str:
    """The opening block of a run report: what ran, the main numbers next to the expert's and the paper's."""
    cfg = _load(run_dir / "config.json")
    ev = _load(run_dir / "eval.json")
    seg = _load(run_dir / "segmentation.json")
    comp = _load(run_dir / "compose.json")
    env = str(cfg.get("env_id") or ev.get("env_id") or "an unknown environment")
    method = METHOD_NAMES.get(str(cfg.get("method") or cfg.get("kind")), str(cfg.get("method") or "a model"))
    train: Mapping[str, Any] = cfg["train"] if isinstance(cfg.get("train"), Mapping) else {}
    steps = _total_steps(run_dir)
    # every piece read from the folder is escaped: a run folder from elsewhere must not put markup in the page
    what = (f"{_esc(method)} on {_esc(env_name(env))} (<code>{_esc(env)}</code>), seed {_esc(cfg.get('seed', 0))}"
            + (f", preset <code>{_esc(cfg['preset'])}</code>" if cfg.get("preset") else "")
            + (f", {_esc(fmt(train['iterations'], 'int'))} training iterations" if train.get("iterations") else "")
            + (f" ({_esc(fmt(steps, 'int'))} environment steps)" if steps else "") + ".")
    rows: list[list[str]] = []
    if ev:
        expert = ev.get("expert") or {}
        paper = paper_return(env)
        rows.append(["mean return ± std (per episode)",
                     f"{fmt(ev.get('mean_return'))} ± {fmt(ev.get('std_return'))}",
                     f"{fmt(expert['mean_return'])} ± {fmt(expert.get('std_return'))}" if expert else "–",
                     f"{fmt(paper[0])} ± {fmt(paper[1])}" if paper else "–"])
        if isinstance(ev.get("normalized_return"), int | float):
            rows.append(["normalised return (agent / expert)", fmt(ev["normalized_return"], "x"), "1 ×", "–"])
        for key in TASK_KEYS:
            if isinstance(ev.get(key), int | float):
                label, kind = _label(key)
                rows.append([label, fmt(ev[key], kind), fmt(expert[key], kind) if key in expert else "–", "–"])
    if "accuracy" in seg:
        rows.append(["segmentation accuracy (demonstrations)", fmt(seg["accuracy"], "pct"), "–", "–"])
    if isinstance(comp.get("order_reversed_rate"), int | float):
        rows.append([f"composed ({_composition_name(comp)}): reversed order drawn",
                     fmt(comp["order_reversed_rate"], "pct"), "–", "–"])
    episodes = f" over {_esc(fmt(ev['episodes'], 'int'))} closed-loop episodes" if ev.get("episodes") else ""
    header = ["", "this run", "expert, same episodes", "paper (Directed-Info GAIL)"]
    if paper_return(env) is None:
        header, rows = header[:3], [r[:3] for r in rows]
    table = _table(header, rows)
    return (f"<section class='headline'><p>{what}</p>"
            f"<p class='meaning'>{_esc(meaning(ev, cfg))}</p>{table}"
            f"<p>Numbers{episodes}; the expert is measured on the same seeds.</p></section>")


def _total_steps(run_dir: Path) -> float | None:
    from digail.viz.figures import read_metrics

    m = read_metrics(run_dir)
    if "step" in m and len(m["step"]):
        return float(m["step"][-1])
    return None


def write_report(run_dir: Path, out: Path | None = None) -> Path:
    """Write RUN/report.html (or `out`) from what the run folder holds; returns its path."""
    run_dir = Path(run_dir)
    cfg = _load(run_dir / "config.json")
    ev = _load(run_dir / "eval.json")
    seg = _load(run_dir / "segmentation.json")
    comp = _load(run_dir / "compose.json")
    timings = _load(run_dir / "timings.json")
    parts = [f"<h1>digail run <code>{_esc(run_dir.name)}</code></h1>", headline(run_dir)]

    videos = run_dir / "videos"
    gifs = sorted(videos.glob("*.gif")) if videos.is_dir() else []
    mp4s = sorted(videos.glob("*.mp4")) if videos.is_dir() else []
    if gifs or mp4s:
        parts.append("<h2>Video</h2>")
        for gif in gifs[:2]:
            parts.append(f"<figure>{_img(gif, gif.stem)}<figcaption>{_esc(gif.stem.replace('_', ' '))}: every frame "
                         "shows the episode, the step and the active code (its colour matches the figures)."
                         "</figcaption></figure>")
        if mp4s:
            page_dir = (Path(out) if out is not None else run_dir / "report.html").resolve().parent
            links = ", ".join(f"<a href='{_esc(Path(os.path.relpath(p.resolve(), page_dir)).as_posix())}'>"
                              f"{_esc(p.name)}</a> ({_file_size(p)})" for p in mp4s)
            parts.append(f"<p>Full-rate MP4 files beside this page: {links}.</p>")

    figs = {p.stem: p for p in sorted((run_dir / "figures").glob("*.png"))} if (run_dir / "figures").is_dir() else {}
    if figs:
        parts.append("<h2>Figures</h2>")
        for stem in sorted(figs, key=lambda s: (FIGURE_ORDER.index(s) if s in FIGURE_ORDER else 99, s)):
            caption = FIGURE_CAPTIONS.get(stem, stem.replace("_", " "))
            parts.append(f"<figure>{_img(figs[stem], stem)}<figcaption>{_esc(caption)}</figcaption></figure>")

    if ev:
        parts.append("<h2>Evaluation (closed-loop macro-policy)</h2>")
        parts.append(_table(["metric", "agent", "expert"], metric_rows([ev, ev.get("expert")])))
        extra = [f"{fmt(ev['episodes'], 'int')} episodes" if ev.get("episodes") else "",
                 f"seeds from {ev['seed']}" if "seed" in ev else "",
                 "deterministic actions" if ev.get("deterministic") else "sampled actions" if "deterministic" in ev
                 else "", str(ev.get("macro_policy", ""))]
        parts.append(f"<p>{_esc('; '.join(x for x in extra if x))}.</p>")
    if seg:
        parts.append("<h2>Segmentation of the demonstrations</h2>")
        if "accuracy" in seg:
            vit = seg.get("viterbi")
            parts.append(_table(["metric", "causal (argmax q)"] + (["Viterbi smoother"] if vit else []),
                                metric_rows([seg, vit] if vit else [seg])))
            if seg.get("mapping"):
                pairs = ", ".join(f"code {c} → label {lab}" for c, lab in sorted(seg["mapping"].items()))
                parts.append(f"<p>Code-to-label matching ({_esc(seg.get('matching', ''))}): {_esc(pairs)}.</p>")
        else:
            parts.append(_table(["metric", "value"], metric_rows([seg])))
            parts.append("<p>The demonstrations carry no oracle labels, so only the switch count is reported.</p>")
    parts.append(_smoothing_table(run_dir))
    if comp:
        kind, text = _composition_name(comp).split(" ", 1)
        parts.append(f"<h2>Composition ({kind} <code>{_esc(text)}</code>)</h2>")
        parts.append(_table(["metric", "value"], metric_rows([comp])))
    if timings:
        parts.append("<h2>Timings</h2>")
        rows = [[TIMING_LABELS.get(k, k.removesuffix("_s").replace("_", " ")), fmt(v, "s")]
                for k, v in timings.items() if isinstance(v, int | float)]
        parts.append(_table(["stage", "wall-clock time"], rows))
    parts.append("<h2>How this run was made</h2>")
    parts.append(f"<pre>{_esc(run_command(cfg))}</pre>")
    shown = {k: v for k, v in cfg.items() if k not in ("args", "schema", "command")}  # args repeat the settings
    if shown:
        parts.append("<details><summary>Full configuration</summary>"
                     + _table(["setting", "value"], _flatten(shown)) + "</details>")
    out = Path(out) if out is not None else run_dir / "report.html"
    atomic_write_bytes(out, _page(f"digail {run_dir.name}", "".join(parts)).encode())
    return out


def _smoothing_table(run_dir: Path) -> str:
    """The scores of the segmentations with and without the smoothing term, when the run folder has both."""
    segs = [_load(run_dir / d / "segmentation.json") for d in (BEFORE_POLISH, UNSMOOTHED)]
    if not all(segs):
        return ""
    weight = ((_load(run_dir / "vae" / "config.json").get("vae") or {}).get("smoothing_weight"))
    with_term = f"with (λs = {fmt(weight)})" if isinstance(weight, int | float) else "with"
    return ("<h3>With and without the smoothing term</h3><p>Two VAEs with the same settings and seed but for the "
            "smoothing weight, both before the polish (figure <i>segmentation_pair</i>).</p>"
            + _table(["metric", with_term, "without (λs = 0)"], metric_rows(segs, SMOOTHING_KEYS)))


# -------------------------------------------------------------------------------------- compare report
def _median(values: Sequence[float]) -> float | None:
    vals = [v for v in values if isinstance(v, int | float) and math.isfinite(v)]
    return statistics.median(vals) if vals else None


def method_of(cfg: Mapping[str, Any]) -> str:
    """How a run is grouped on the compare page: its method (and K when the VAE settings give it)."""
    method = str(cfg.get("method") or cfg.get("kind") or "unknown")
    bc = (cfg.get("train") or {}).get("bc_weight")
    return METHOD_NAMES.get(method, method) + (" + L2" if isinstance(bc, int | float) and bc > 0 else "")


def _seeds(n: int) -> str:
    return f"{n} seed" if n == 1 else f"{n} seeds"


def compare_figure(out: Path) -> Path:
    """The learning-curves figure a comparison page `out` is written with, beside it (and embedded in it)."""
    return Path(out).with_name(Path(out).stem + "_learning_curves.png")


def write_compare_report(runs: Sequence[Path], out: Path) -> Path:
    """One page over many run folders: learning curves (mean and spread over seeds per method) and tables of
    medians and of each seed's main numbers. Returns `out`."""
    from digail.viz.figures import learning_curves_multi

    runs = [Path(r) for r in runs]
    groups: dict[str, list[Path]] = {}
    info: dict[Path, tuple[dict[str, Any], dict[str, Any], dict[str, Any]]] = {}
    for r in runs:
        info[r] = (_load(r / "config.json"), _load(r / "eval.json"), _load(r / "segmentation.json"))
    envs = sorted({str(c.get("env_id")) for c, _, _ in info.values() if c.get("env_id")})
    for r in runs:
        cfg = info[r][0]
        env = str(cfg.get("env_id"))
        # runs on different envs never share a row or a curve
        key = method_of(cfg) + (f" on {env_name(env)}" if len(envs) > 1 else "")
        groups.setdefault(key, []).append(r)
    out = Path(out)
    fig_path = compare_figure(out)
    existed = fig_path.exists()
    fig = learning_curves_multi(groups, fig_path)
    keys = ["mean_return", "normalized_return", *TASK_KEYS]
    present = [k for k in keys if any(isinstance(ev.get(k), int | float) for _, ev, _ in info.values())]
    has_seg = any("accuracy" in s for _, _, s in info.values())
    header = ["method", "seeds"] + [_label(k)[0] for k in present] + (["segmentation accuracy"] if has_seg else [])
    rows = []
    for method, rs in sorted(groups.items()):
        row = [method, str(len(rs))]
        for k in present:
            m = _median([info[r][1].get(k) for r in rs])  # type: ignore[misc]
            row.append(fmt(m, _label(k)[1]) if m is not None else "–")
        if has_seg:
            m = _median([info[r][2].get("accuracy") for r in rs])  # type: ignore[misc]
            row.append(fmt(m, "pct") if m is not None else "–")
        rows.append(row)
    per_seed = []
    for method, rs in sorted(groups.items()):
        for r in sorted(rs, key=lambda p: info[p][0].get("seed", 0)):
            cfg, ev, seg = info[r]
            per_seed.append([method, str(cfg.get("seed", "–"))]
                            + [fmt(ev[k], _label(k)[1]) if isinstance(ev.get(k), int | float) else "–" for k in present]
                            + ([fmt(seg["accuracy"], "pct") if "accuracy" in seg else "–"] if has_seg else [])
                            + [r.name])
    env_names = ", ".join(env_name(e) for e in envs) or "unknown environments"
    parts = [f"<h1>digail: {len(groups)} method(s) × seeds on {_esc(env_names)}</h1>" if len(envs) <= 1
             else f"<h1>digail: {len(groups)} methods and environments × seeds</h1>",
             "<section class='headline'>"
             f"<p>{len(runs)} runs: " + ", ".join(f"{_esc(m)} ({_seeds(len(rs))})" for m, rs in sorted(groups.items()))
             + ". Medians over seeds; evaluation is closed-loop.</p>" + _table(header, rows) + "</section>"]
    if fig is not None:
        parts.append("<h2>Learning curves</h2><figure>" + _img(fig, "learning curves")
                     + "<figcaption>Mean over seeds (line) and min–max over seeds (band) against environment steps."
                     "</figcaption></figure>")
    parts.append("<h2>Every run</h2>" + _table(header[:1] + ["seed"] + header[2:] + ["run folder"], per_seed))
    try:
        atomic_write_bytes(out, _page("digail comparison", "".join(parts)).encode())
    except BaseException:
        if fig is not None and not existed:  # no figure left beside a page that was never written
            fig_path.unlink(missing_ok=True)
        raise
    return out
