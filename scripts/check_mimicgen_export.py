"""Step 1 of scripts/check_mimicgen_signals.py, in digail's venv, writing into $MG_CHECK_OUT (default runs/mg_check):

- the robomimic fixture's known phases (reach=0, carry=1) exported as check_format_exports.py does, and digail's
  own segment table (csv export of the same codes) beside it;
- `recurring-robomimic.hdf5`: an export of codes that recur within a demonstration and give the demonstrations
  different numbers of segments (the case MimicGen's parser refused or merged before the export fitted one
  boundary per sub-task), with `recurring.plan.json`: the task spec order the export announced and each
  demonstration's boundaries, which MimicGen's parser must reproduce;
- with `--robosuite-export FILE` (an export `digail segment --export robomimic` wrote of a robosuite file), that
  file's plan read back the same way, to be parsed by MimicGen too.
"""
import argparse
import json
import os
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# run as a script, so its own folder (scripts/) is already where imports look
from format_fixture_episodes import episodes  # noqa: E402

from digail.data.annotations import export_segmentation  # noqa: E402
from digail.data.importers import read_demonstrations  # noqa: E402
from digail.data.robomimic import SIGNALS_PATH, plan_subtasks  # noqa: E402

NAMES = ["reach", "carry"]
OUT = Path(os.environ.get("MG_CHECK_OUT", "runs/mg_check"))
parser = argparse.ArgumentParser()
parser.add_argument("--robosuite-export", type=Path)
args = parser.parse_args()
phases = [e["phase"] for e in episodes()]
im = read_demonstrations(ROOT / "tests/data/formats/robomimic_robosuite.hdf5")
codes = [p[:len(t)] for p, t in zip(phases, im.trajs, strict=True)]
for fmt, name in (("robomimic", "annotated-robomimic.hdf5"), ("csv", "segments.csv")):
    out = export_segmentation(fmt, OUT / name, im.episode_keys, codes, NAMES, source=im.source, force=True)
    print(fmt, "->", out)

# codes that recur and differ in segment count: 0 1 0 1 2 / 0 2 1 2 / 0 0 1 2 1 2 ...
rng = np.random.default_rng(0)
recurring = []
for t in im.trajs:
    n = len(t)
    c = np.minimum(np.arange(n) * 3 // n, 2)  # three sub-tasks in order
    flips = rng.choice(np.arange(1, n - 1), size=3, replace=False)
    c[flips] = rng.integers(0, 3, size=3)  # one-step relapses and jumps ahead
    recurring.append(c)
names = ["approach", "hold", "leave"]
notes: list[str] = []
out = export_segmentation("robomimic", OUT / "recurring-robomimic.hdf5", im.episode_keys, recurring, names,
                          source=im.source, force=True, notes=notes)
with h5py.File(im.source, "r") as f:  # a demonstration read without its last action exports it with the code before
    steps = [int(f[f"data/{k}/actions"].shape[0]) for k in im.episode_keys]
plan = plan_subtasks([np.pad(c, (0, n - len(c)), mode="edge") for c, n in zip(recurring, steps, strict=True)],
                     len(names))
print("recurring ->", out, "|", notes[0])
runs = {k: [int(c[0]), *[int(c[j]) for j in np.flatnonzero(np.diff(c)) + 1]] for k, c in
        zip(im.episode_keys, recurring, strict=True)}
(OUT / "recurring.plan.json").write_text(json.dumps({
    "note": notes[0], "spec": [*[names[k] for k in plan.order[:-1]], None],
    "boundaries": dict(zip(im.episode_keys, [list(b) for b in plan.boundaries], strict=True)),
    "code_runs": runs}, indent=1) + "\n")

if args.robosuite_export is not None:
    with h5py.File(args.robosuite_export, "r") as f:
        keys = sorted(f["data"], key=lambda k: int(k.split("_")[1]))
        firsts = {}
        for key in keys:
            group = f[f"data/{key}/{SIGNALS_PATH}"]
            ours = json.loads(group.attrs["digail_signals"])
            firsts[key] = {n: int(np.flatnonzero(group[n][()])[0]) for n in ours if group[n][()].any()}
    order = sorted(firsts[keys[0]], key=lambda n: firsts[keys[0]][n])
    (OUT / "robosuite.plan.json").write_text(json.dumps({
        "file": str(args.robosuite_export), "spec": [*order, None],
        "boundaries": {k: [firsts[k][n] for n in order] for k in keys}}, indent=1) + "\n")
    print("robosuite export plan ->", OUT / "robosuite.plan.json")
