"""Peer segmenters on the segmentation benchmark's data, scored exactly as digail is.

    python benchmarks/segmentation_peers.py     # every task, every peer, seeds 0 1 2
        -> benchmarks/results/segmentation/segmentation_peers.json
    python benchmarks/segmentation_peers.py --tasks metaworld-hammer --peers hmm-actions --seeds 0
    python benchmarks/segmentation_peers.py --table
        -> the markdown table (digail against each peer, from segmentation.json and segmentation_peers.json) and
           benchmarks/results/figures/segmentation_peers.png; cheap, rerun it whenever either file changes

Needs the benchmark extra: `pip install -e ".[bench]"`.

The tasks and their data sets are those of `benchmarks/segmentation.py`, read from it at run time (its
`task_names()`, Meta-World tasks first, and the Meta-World tasks whose shipped demonstrations exist but which that
module does not list yet). Every peer gets K = the task's number of distinct oracle labels, as digail does, and the
same scorer (`digail.eval.segmentation.segmentation_metrics`: accuracy after Hungarian matching, NMI, boundary F1
at its default tolerance of 2 steps, switches per episode), plus boundary F1 at +-5 steps. The peers:

- `hmm-actions`: hmmlearn's `GaussianHMM` (full covariance) on the standardised actions; the best of 5 restarts
  by log-likelihood; codes = the Viterbi path of each episode.
- `hmm-states-actions`: the same on standardised [state, action].
- `kernel-cpd-told`: ruptures' `KernelCPD(kernel="rbf")` on each episode's standardised actions, TOLD the true
  number of segments of that episode (an advantage digail does not get), then k-means (K clusters, 10 starts) on
  each segment's mean standardised action and mean standardised state, the two blocks weighted equally.
- `linreg-hmm`: dynamax's `LinearRegressionHMM`, a switching linear policy a_t ~ N(W_k s_t + b_k, S_k) with a
  Markov chain over k (the textbook model closest to digail's: one linear sub-task policy per code) on the
  standardised states and actions, fit by EM from the best of 5 k-means starts by log-likelihood; codes = the
  Viterbi path.

Seeds seed the restarts (restart r of seed s uses 1000 s + r) and k-means. Rows already in the output are kept and
skipped, so an interrupted run resumes; each row records the command that made it.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shlex
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results" / "segmentation"
OUT = RESULTS / "segmentation_peers.json"
DIGAIL = RESULTS / "segmentation.json"
FIGURE = HERE / "results" / "figures" / "segmentation_peers.png"

PEERS = ("hmm-actions", "hmm-states-actions", "kernel-cpd-told", "linreg-hmm")
TOLD = {"kernel-cpd-told"}
"""peers told the true number of segments of every episode (digail is not)"""
TOLD_NOTE = ("kernel-cpd-told is told the true number of segments of every episode, an advantage digail and the "
             "other peers do not get")
RESTARTS = 5
NEW_METAWORLD = ("push-wall", "plate-slide-back", "stick-push", "door-lock", "hand-insert", "pick-out-of-hole",
                 "coffee-pull")
"""Meta-World tasks being added to the benchmark: run once their shipped demonstrations exist, even before
`benchmarks/segmentation.py` lists them"""
SEGMENTERS: dict[str, Callable[..., list[np.ndarray]]] = {}


# --------------------------------------------------------------------------------------------- features
def standardise(parts: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Per-dimension z-scores over all steps of all episodes. Constant dimensions (Meta-World's unused object slots)
    are dropped: they carry nothing and would leave a full covariance singular."""
    flat = np.concatenate(parts)
    mean, std = flat.mean(0), flat.std(0)
    keep = std > 1e-8
    if not keep.any():
        keep[:] = True
    std = np.where(keep, std, 1.0)
    return [((p - mean) / std)[:, keep].astype(np.float64) for p in parts]


def features(trajs: Sequence[Any]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(standardised actions, standardised states) per episode, one row per action; discrete actions one-hot."""
    acts = [np.asarray(t.acts) for t in trajs]
    if np.issubdtype(acts[0].dtype, np.integer):
        n = int(max(a.max() for a in acts)) + 1
        acts = [np.eye(n)[a.reshape(-1)] for a in acts]
    acts = [a.reshape(len(a), -1).astype(np.float64) for a in acts]
    states = [np.asarray(t.obs, np.float64).reshape(len(t.obs), -1)[:len(a)] for t, a in zip(trajs, acts,
                                                                                                strict=True)]
    return standardise(acts), standardise(states)


def _split(path: np.ndarray, lengths: Sequence[int]) -> list[np.ndarray]:
    return [np.asarray(p, np.int64) for p in np.split(path, np.cumsum(lengths)[:-1])]


# --------------------------------------------------------------------------------------------- peers
def gaussian_hmm(xs: Sequence[np.ndarray], codes: int, seed: int, restarts: int = RESTARTS,
                 covariance: str = "full") -> list[np.ndarray]:
    """hmmlearn's GaussianHMM on the per-episode rows `xs`: best of `restarts` fits by log-likelihood, Viterbi."""
    from hmmlearn.hmm import GaussianHMM

    logging.getLogger("hmmlearn").setLevel(logging.ERROR)  # "not converging" notes on tiny likelihood dips
    x, lengths = np.concatenate(xs), [len(e) for e in xs]
    best, best_score = None, -np.inf
    for r in range(restarts):
        model = GaussianHMM(n_components=codes, covariance_type=covariance, n_iter=100, tol=1e-3,
                            random_state=1000 * seed + r)
        try:
            model.fit(x, lengths)
            score = model.score(x, lengths)
        except (ValueError, np.linalg.LinAlgError):  # a degenerate start (a state with no rows); the next one
            continue
        if np.isfinite(score) and score > best_score:
            best, best_score = model, score
    if best is None:
        raise RuntimeError("every GaussianHMM restart failed")
    return _split(best.predict(x, lengths), lengths)


def hmm_actions(acts: Sequence[np.ndarray], states: Sequence[np.ndarray], codes: int, seed: int,
                **_: Any) -> list[np.ndarray]:
    return gaussian_hmm(acts, codes, seed)


def hmm_states_actions(acts: Sequence[np.ndarray], states: Sequence[np.ndarray], codes: int, seed: int,
                       **_: Any) -> list[np.ndarray]:
    return gaussian_hmm([np.hstack([s, a]) for s, a in zip(states, acts, strict=True)], codes, seed)


def segment_counts(labels: Sequence[np.ndarray]) -> list[int]:
    """Number of constant runs of each episode's labels: what `kernel-cpd-told` is told."""
    return [1 + int(np.count_nonzero(lab[1:] != lab[:-1])) for lab in labels]


def kernel_cpd_told(acts: Sequence[np.ndarray], states: Sequence[np.ndarray], codes: int, seed: int,
                    segments: Sequence[int], **_: Any) -> list[np.ndarray]:
    """ruptures' KernelCPD (rbf) per episode with its true segment count, then k-means over the segments.

    A segment is described by its mean standardised action and mean standardised state, each block divided by the
    square root of its width so that Meta-World's 39 state dimensions do not drown its 4 action dimensions.
    """
    import ruptures
    from sklearn.cluster import KMeans

    bounds, rows = [], []
    for a, s, n in zip(acts, states, segments, strict=True):
        n = min(n, len(a))  # cannot cut more often than there are steps
        ends = ruptures.KernelCPD(kernel="rbf", min_size=1).fit(a).predict(n_bkps=n - 1) if n > 1 else [len(a)]
        starts = [0, *ends[:-1]]
        bounds.append(list(zip(starts, ends, strict=True)))
        rows += [np.r_[a[i:j].mean(0) / np.sqrt(a.shape[1]), s[i:j].mean(0) / np.sqrt(s.shape[1])]
                 for i, j in zip(starts, ends, strict=True)]
    k = min(codes, len(rows))
    labels = KMeans(n_clusters=k, n_init=10, random_state=seed).fit_predict(np.array(rows))
    out, i = [], 0
    for episode in bounds:
        code = np.empty(episode[-1][1], np.int64)
        for start, end in episode:
            code[start:end] = labels[i]
            i += 1
        out.append(code)
    return out


def linreg_hmm(acts: Sequence[np.ndarray], states: Sequence[np.ndarray], codes: int, seed: int,
               restarts: int = RESTARTS, jitter: float = 0.03, **_: Any) -> list[np.ndarray]:
    """dynamax's LinearRegressionHMM (a_t ~ N(W_k s_t + b_k, S_k)): best of `restarts` EM fits, Viterbi.

    dynamax's M-step has no covariance floor, and clipped actions (Meta-World's, at +-1 for many steps) make a
    regime's covariance singular at once; so the standardised actions get seeded Gaussian noise of std `jitter`
    (0.03: variance 1e-3, hmmlearn's `min_covar`) and the fit runs in float64. The episodes are fit and decoded as
    one concatenated sequence (dynamax batches only equal lengths; the transitions across episode ends, last phase
    to first, are a negligible share of the counts).
    """
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    import jax
    import jax.numpy as jnp
    from dynamax.hidden_markov_model import LinearRegressionHMM

    jax.config.update("jax_enable_x64", True)
    y_clean = np.concatenate(acts)
    y = jnp.asarray(y_clean + jitter * np.random.default_rng(seed).standard_normal(y_clean.shape))
    x = jnp.asarray(np.concatenate(states))
    hmm = LinearRegressionHMM(codes, x.shape[1], y.shape[1])
    best, best_ll = None, -np.inf
    for r in range(restarts):
        params, props = hmm.initialize(jax.random.PRNGKey(1000 * seed + r), method="kmeans", emissions=y)
        params, _ = hmm.fit_em(params, props, y, inputs=x, num_iters=100, verbose=False)
        ll = float(hmm.marginal_log_prob(params, y, inputs=x))
        if np.isfinite(ll) and ll > best_ll:
            best, best_ll = params, ll
    if best is None:
        raise RuntimeError("every LinearRegressionHMM restart diverged")
    return _split(np.asarray(hmm.most_likely_states(best, y, inputs=x)), [len(a) for a in acts])


SEGMENTERS.update({"hmm-actions": hmm_actions, "hmm-states-actions": hmm_states_actions,
                   "kernel-cpd-told": kernel_cpd_told, "linreg-hmm": linreg_hmm})


# --------------------------------------------------------------------------------------------- scoring
def score(codes: Sequence[np.ndarray], labels: Sequence[np.ndarray]) -> dict[str, Any]:
    """digail's scorer: its defaults (boundary tolerance 2 steps, as in digail's table) and boundary F1 at +-5."""
    from digail.eval.segmentation import segmentation_metrics

    m = segmentation_metrics(codes, labels)
    m5 = segmentation_metrics(codes, labels, tolerance=5)
    return {"accuracy": m["accuracy"], "nmi": m["nmi"], "boundary_f1": m["boundary_f1"],
            "boundary_f1_5": m5["boundary_f1"], "switches_per_episode": m["switches_per_episode"],
            "true_switches_per_episode": m["true_switches_per_episode"], "matching": m["matching"]}


def run_peer(peer: str, trajs: Sequence[Any], codes: int, seed: int) -> dict[str, Any]:
    """Segment `trajs` with `peer` (K = `codes`) and score it against their oracle labels."""
    labels = [np.asarray(t.subtasks)[:len(t.acts)] for t in trajs]
    acts, states = features(trajs)
    t0 = time.perf_counter()
    found = SEGMENTERS[peer](acts, states, codes, seed, segments=segment_counts(labels))
    elapsed = time.perf_counter() - t0
    return {**score(found, labels), "time_s": round(elapsed, 1)}


# --------------------------------------------------------------------------------------------- tasks
def benchmark_module() -> Any:
    """benchmarks/segmentation.py, loaded from its file now so that tasks added to it are picked up (by path, so
    nothing is put on `sys.path`)."""
    import importlib.util

    if "segmentation" in sys.modules and getattr(sys.modules["segmentation"], "__file__", None) == str(
            HERE / "segmentation.py"):
        return sys.modules["segmentation"]
    spec = importlib.util.spec_from_file_location("segmentation", HERE / "segmentation.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["segmentation"] = module
    spec.loader.exec_module(module)
    return module


def task_list(bench: Any) -> list[str]:
    """The benchmark's tasks, Meta-World first (the ones the peers are measured for), then the cheap older ones;
    plus the new Meta-World tasks whose shipped demonstrations exist."""
    from digail.data.minari_io import resolve_dataset

    names = list(bench.task_names())
    for task in NEW_METAWORLD:
        name = f"metaworld-{task}"
        if name in names:
            continue
        try:
            resolve_dataset(f"digail/{name}/expert-v0")
        except Exception:  # not recorded yet
            continue
        names.append(name)
    return sorted(names, key=lambda n: not n.startswith("metaworld-"))


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", help="default: every task of benchmarks/segmentation.py")
    parser.add_argument("--peers", nargs="+", default=list(PEERS), choices=PEERS)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--data", type=Path, default=Path("runs/segbench/datasets"),
                        help="where benchmarks/segmentation.py writes the data sets it derives")
    parser.add_argument("--table", action="store_true", help="only write the table and the figure from the JSON")
    parser.add_argument("--digail", type=Path, default=DIGAIL, help="digail's results, for --table")
    parser.add_argument("--figure", type=Path, default=FIGURE)
    args = parser.parse_args(argv)
    if args.table:
        peers = json.loads(args.out.read_text())
        ours = json.loads(args.digail.read_text()) if args.digail.exists() else {"tasks": {}}
        print(merged_table(ours, peers))
        accuracy_figure(ours, peers, args.figure)
        return
    os.environ.setdefault("MUJOCO_GL", "egl")
    from digail.data.minari_io import load_dataset

    bench = benchmark_module()
    tasks = args.tasks or task_list(bench)
    command = shlex.join(["python", "benchmarks/segmentation_peers.py", *argv])
    result: dict[str, Any] = {"note": TOLD_NOTE, "told_segment_count": sorted(TOLD), "tasks": {}}
    if args.out.exists():
        result.update(json.loads(args.out.read_text()))
    result["commands"] = sorted({*result.get("commands", []), command})
    for name in tasks:
        demos, codes, _, description = bench.task_data(name, args.data)
        entry = result["tasks"].setdefault(name, {"description": description, "codes": codes, "demos": demos,
                                                  "peers": {}})
        trajs = None
        for peer in args.peers:
            rows = entry["peers"].setdefault(peer, {"seeds": []})
            for seed in args.seeds:
                if any(r["seed"] == seed for r in rows["seeds"]):
                    continue
                trajs = load_dataset(demos).trajs if trajs is None else trajs
                try:
                    row = {"seed": seed, **run_peer(peer, trajs, codes, seed), "command": command}
                except RuntimeError as err:  # e.g. every EM start diverged: recorded, and the other rows go on
                    failure = {"task": name, "peer": peer, "seed": seed, "error": str(err), "command": command}
                    result["failures"] = [*(f for f in result.get("failures", [])
                                            if (f["task"], f["peer"], f["seed"]) != (name, peer, seed)), failure]
                    args.out.write_text(json.dumps(result, indent=1) + "\n")
                    print(f"== {name} {peer} seed {seed}: FAILED ({err})", flush=True)
                    continue
                rows["seeds"] = sorted([*rows["seeds"], row], key=lambda r: r["seed"])
                rows["median"] = median(rows["seeds"])
                print(f"== {name} {peer} seed {seed}: accuracy {row['accuracy']:.3f}  NMI {row['nmi']:.3f}  "
                      f"F1 {row['boundary_f1']:.3f} (+-5: {row['boundary_f1_5']:.3f})  switches "
                      f"{row['switches_per_episode']:.2f} (truth {row['true_switches_per_episode']:.2f})  "
                      f"{row['time_s']:.0f} s", flush=True)
                args.out.parent.mkdir(parents=True, exist_ok=True)
                args.out.write_text(json.dumps(result, indent=1) + "\n")  # after every row: resumable


KEYS = ("accuracy", "nmi", "boundary_f1", "boundary_f1_5", "switches_per_episode", "true_switches_per_episode",
        "time_s")


def median(rows: Sequence[dict[str, Any]]) -> dict[str, float]:
    return {k: float(np.median([r[k] for r in rows])) for k in KEYS if all(k in r for r in rows)}


# --------------------------------------------------------------------------------------------- table, figure
def _peer_accuracy(task: dict[str, Any], peer: str) -> float | None:
    med = task["peers"].get(peer, {}).get("median")
    return None if med is None else med["accuracy"]


def merged_table(ours: dict[str, Any], peers: dict[str, Any]) -> str:
    """Markdown: per task the median accuracy of digail and of each peer, the best peer and digail - best peer;
    then the median over the Meta-World tasks both have. `*` marks the peer told the true segment counts."""
    names = [p for p in PEERS if any(p in t["peers"] for t in peers["tasks"].values())]
    head = [f"{p} *" if p in TOLD else p for p in names]
    lines = ["| task | K | digail | " + " | ".join(head) + " | best peer | digail - best peer |",
             "| --- | --- | --- | " + " | ".join("---" for _ in head) + " | --- | --- |"]
    most = max((len(r.get("seeds", [])) for t in peers["tasks"].values() for r in t["peers"].values()), default=0)
    diffs: list[float] = []
    columns: dict[str, list[float]] = {"digail": [], **{p: [] for p in names}}  # Meta-World tasks with every cell
    for name, task in peers["tasks"].items():
        digail = ours.get("tasks", {}).get(name, {}).get("median", {}).get("accuracy")
        accs = {p: _peer_accuracy(task, p) for p in names}
        known = {p: a for p, a in accs.items() if a is not None}
        best = max(known, key=known.__getitem__) if known else None
        seeds = {p: len(task["peers"].get(p, {}).get("seeds", [])) for p in names}
        # a cell measured on fewer seeds than the others (a run still going) says so
        cells = [("-" if a is None else f"{a:.3f}" + (f" ({seeds[p]} of {most})" if 0 < seeds[p] < most else ""))
                 for p, a in accs.items()]
        gap = "-"
        if best is not None and digail is not None:
            gap = f"{digail - known[best]:+.3f}"
            if name.startswith("metaworld-") and len(known) == len(names):
                diffs.append(digail - known[best])
                columns["digail"].append(digail)
                for p in names:
                    columns[p].append(known[p])
        lines.append(f"| {name} | {task['codes']} | {'-' if digail is None else f'{digail:.3f}'} | "
                     + " | ".join(cells) + f" | {best or '-'} | {gap} |")
    if diffs:
        meds = {k: float(np.median(v)) for k, v in columns.items()}
        best = max(names, key=meds.__getitem__)
        lines.append(f"| median, {len(diffs)} Meta-World tasks | | {meds['digail']:.3f} | "
                     + " | ".join(f"{meds[p]:.3f}" for p in names)
                     + f" | {best} | {meds['digail'] - meds[best]:+.3f} |")
        lines.append(f"\nMedian of digail - best peer (per task) over the {len(diffs)} Meta-World tasks: "
                     f"{float(np.median(diffs)):+.3f}.")
    lines.append(f"\nMedian accuracy over seeds. * {TOLD_NOTE}.")
    return "\n".join(lines)


def accuracy_figure(ours: dict[str, Any], peers: dict[str, Any], out: Path) -> None:
    """Per-task bars of median accuracy: digail and each peer."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [p for p in PEERS if any(p in t["peers"] for t in peers["tasks"].values())]
    tasks = list(peers["tasks"])
    series = {"digail": [ours.get("tasks", {}).get(t, {}).get("median", {}).get("accuracy", np.nan) for t in tasks]}
    for p in names:
        label = f"{p} (told the segment counts)" if p in TOLD else p
        series[label] = [np.nan if (a := _peer_accuracy(peers["tasks"][t], p)) is None else a for t in tasks]
    width = 0.8 / len(series)
    fig, ax = plt.subplots(figsize=(max(8.0, 0.7 * len(tasks) + 4), 4.2))
    x = np.arange(len(tasks))
    for i, (label, values) in enumerate(series.items()):
        ax.bar(x + (i - (len(series) - 1) / 2) * width, values, width, label=label)
    ax.set_xticks(x, tasks, rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("accuracy (median over seeds)")
    ax.set_ylim(0, 1.02)
    ax.axhline(0.9, color="grey", lw=0.6, ls="--")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax.set_title("Segmentation: digail's defaults against peer segmenters, same data, same scorer, K given",
                 fontsize=9)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    print(f"wrote {_rel(out)}")


def _rel(path: Path) -> str:
    try:
        return path.resolve().relative_to(ROOT).as_posix()
    except ValueError:
        return str(path)


if __name__ == "__main__":
    main()
