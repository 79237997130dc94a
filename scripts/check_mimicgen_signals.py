"""Check digail's robomimic export (MimicGen `datagen_info/subtask_term_signals/<name>`) with MimicGen's own parser,
`mimicgen.utils.file_utils.parse_source_dataset` (NVlabs/mimicgen, source on PYTHONPATH; not on PyPI).

Run in robomimic 0.3.0's venv:

    PYTHONPATH=MIMICGEN_SOURCE ROBOMIMIC_VENV/bin/python scripts/check_mimicgen_signals.py

It (1) exports the robomimic format fixture's known phases (reach, carry) with digail, as
scripts/check_format_exports.py does, plus the same codes as digail's csv segment table (run in digail's venv via
scripts/check_mimicgen_export.py); (2) calls parse_source_dataset on the export as is (expected to fail: the export
has only subtask_term_signals, not the poses MimicGen's prepare_src_dataset.py adds); (3) calls it on a harness copy
with placeholder eef_pose / target_pose / gripper_action / object_poses added (signals untouched); (4) compares the
subtask indices MimicGen derives with digail's segments and writes $MG_CHECK_OUT/mimicgen.check.json (the committed
record: tests/data/formats/mimicgen.check.json).
No imports are stubbed: mimicgen/__init__.py catches the ImportError of robosuite itself. Where
`mimicgen.utils.file_utils` cannot be imported (its module-level imports pull robomimic's models, hence torchvision,
whose CPU build PyPI does not carry), the two functions used are taken verbatim from that file's source and run
with the names they use (h5py, numpy, tqdm, MimicGen's own DatagenInfo); the record says which way it ran.

(5) It also parses, with the task spec the export announced in its one line, an export of codes that recur within
demonstrations and give them different numbers of segments (`recurring-robomimic.hdf5`), and, given
`--robosuite-export FILE` (passed on to step 1), a `digail segment --export robomimic` export of robosuite
demonstrations: every demonstration must parse, into the boundaries digail's plan gave it (+1, MimicGen's rule).
"""
import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
from check_mimicgen_offsets import with_placeholder_poses  # scripts/ is on the path of a script run there

MAIN = Path(os.environ.get("DIGAIL_ROOT", Path(__file__).resolve().parents[1]))
OUT = Path(os.environ.get("MG_CHECK_OUT", "runs/mg_check"))
MG_COMMIT = os.environ.get("MIMICGEN_COMMIT", "72bd767c255545f462e7ccfb2731f2e5d4c1d9bb")
EXPORT = OUT / "annotated-robomimic.hdf5"
HARNESS = OUT / "annotated-robomimic.with-placeholder-poses.hdf5"
SEGMENTS = OUT / "segments.csv"

# 1. digail export (digail's own venv)
DIGAIL_PYTHON = os.environ.get("DIGAIL_PYTHON", str(MAIN / ".venv/bin/python"))
subprocess.run([DIGAIL_PYTHON, str(MAIN / "scripts" / "check_mimicgen_export.py"), *sys.argv[1:]], check=True,
               cwd=MAIN, env={**os.environ, "PYTHONPATH": str(MAIN / "src")})

try:
    import mimicgen.utils.file_utils as MG_FileUtils  # noqa: E402  (the source checkout is on PYTHONPATH)
    HOW = "imported mimicgen.utils.file_utils"
except (ImportError, RuntimeError) as exc:
    import types

    import mimicgen  # noqa: E402
    from mimicgen.datagen.datagen_info import DatagenInfo  # noqa: E402
    from tqdm import tqdm  # noqa: E402

    text = (Path(mimicgen.__file__).parent / "utils" / "file_utils.py").read_text()
    namespace = {"h5py": h5py, "np": np, "tqdm": tqdm, "DatagenInfo": DatagenInfo}
    for fn in ("get_all_demos_from_dataset", "parse_source_dataset"):
        start = text.index(f"def {fn}(")
        end = text.index("\ndef ", start + 1)
        exec(compile(text[start:end], "mimicgen/utils/file_utils.py", "exec"), namespace)
    MG_FileUtils = types.SimpleNamespace(**{k: namespace[k] for k in ("get_all_demos_from_dataset",
                                                                     "parse_source_dataset")})
    HOW = (f"mimicgen.utils.file_utils does not import here ({type(exc).__name__}: {exc}); its functions "
           "get_all_demos_from_dataset and parse_source_dataset were run verbatim from its source with h5py, numpy, "
           "tqdm and mimicgen.datagen.datagen_info.DatagenInfo")
print(HOW)

# digail's segments per demo, in order
segs = {}
with open(SEGMENTS) as f:
    for row in csv.DictReader(f):
        segs.setdefault(row["episode"], []).append((int(row["start"]), int(row["end"]), row["name"]))
orders = {tuple(n for _, _, n in s) for s in segs.values()}
assert len(orders) == 1, f"demos differ in sub-task order: {orders}"
subtask_names = list(orders.pop())
with h5py.File(EXPORT, "r") as f:
    exported = json.loads(f["data/demo_0/datagen_info/subtask_term_signals"].attrs["digail_signals"])
assert sorted(exported) == sorted(subtask_names), (exported, subtask_names)
# MimicGen's task spec: one termination signal per sub-task, None for the last (it ends with the demo)
term_signals = [*subtask_names[:-1], None]
offsets = [(0, 0)] * len(term_signals)
demo_keys = MG_FileUtils.get_all_demos_from_dataset(dataset_path=str(EXPORT))


def parse(path, signals, keys=None):
    return MG_FileUtils.parse_source_dataset(dataset_path=str(path), demo_keys=keys or demo_keys,
                                             subtask_term_signals=list(signals),
                                             subtask_term_offset_ranges=[(0, 0)] * len(signals))


def check_plan(name, export, plan_file):
    """Parse an export with the spec its plan announced; every demonstration's ends must be its boundaries + 1."""
    plan = json.loads(plan_file.read_text())
    path = with_placeholder_poses(export, OUT / f"{name}.with-placeholder-poses.hdf5")
    keys = MG_FileUtils.get_all_demos_from_dataset(dataset_path=str(path))
    try:
        _, indices, _, _ = parse(path, plan["spec"], keys)
    except AssertionError as e:
        return {"pass": False, "error": str(e), "spec": plan["spec"]}
    got = {k: [int(x) for x in indices[i][:, 1]] for i, k in enumerate(keys)}
    with h5py.File(path, "r") as f:
        want = {k: [b + 1 for b in plan["boundaries"][k]] + [int(f[f"data/{k}/actions"].shape[0])] for k in keys}
    ok = got == want
    print(name, "PASS" if ok else "FAIL", "spec", plan["spec"], "| demos", len(keys))
    return {"pass": bool(ok), "spec": plan["spec"], "demos": len(keys), "note": plan.get("note"),
            "code_runs": plan.get("code_runs"), "mimicgen_subtask_ends": got if len(keys) <= 10 else
            {k: got[k] for k in keys[:10]}, "expected_ends_from_digail_plan": want if len(keys) <= 10 else
            {k: want[k] for k in keys[:10]}, "file": str(export)}


# 2. the export as is
try:
    parse(EXPORT, term_signals)
    raw = "parsed"
except KeyError as e:
    raw = f"KeyError {e} (datagen_info has only subtask_term_signals; the poses come from prepare_src_dataset.py)"
print("export as is:", raw)

# 3. harness copy: placeholder poses, signals untouched
with_placeholder_poses(EXPORT, HARNESS)
datagen_infos, subtask_indices, _, _ = parse(HARNESS, term_signals)
# the fixture's oracle signal `grasp` (written as MimicGen's annotate_subtasks.py writes signals) for comparison
_, grasp_indices, _, _ = parse(HARNESS, ["grasp", None])

# 4. compare
per_demo, ok_plus1, ok_equal = {}, True, True
with h5py.File(EXPORT, "r") as f:
    for i, key in enumerate(demo_keys):
        T = f[f"data/{key}/actions"].shape[0]
        d_ends = [e for _, e, _ in segs[key]]
        d_starts = [s for s, _, _ in segs[key]]
        mg = subtask_indices[i].tolist()
        mg_ends = [b for _, b in mg]
        # MimicGen's convention: a non-final sub-task's parsed end = first step its signal is 1, plus 1
        expect = [e + 1 for e in d_ends[:-1]] + [d_ends[-1]]
        # what MimicGen's annotate_subtasks.py writes for end index e: ones(T); [:e] = 0
        annot = {}
        for (_start, e, n) in segs[key][:-1]:
            a = np.ones(T, dtype=int)
            a[:e] = 0
            annot[n] = bool(np.array_equal(a, f[f"data/{key}/datagen_info/subtask_term_signals/{n}"][()]))
        first_one = {n: int(np.flatnonzero(f[f"data/{key}/datagen_info/subtask_term_signals/{n}"][()])[0])
                     for n in subtask_names[:-1]}
        per_demo[key] = {
            "T": T, "digail_segments": [[s, e, n] for s, e, n in segs[key]],
            "mimicgen_subtask_indices": mg, "mimicgen_grasp_oracle_indices": grasp_indices[i].tolist(),
            "first_step_signal_is_1": first_one, "signals_equal_annotate_subtasks_output": annot,
        }
        ok_plus1 &= mg_ends == expect and all(annot.values()) and d_ends[-1] == T
        ok_plus1 &= grasp_indices[i].tolist() == mg
        ok_equal &= mg_ends == d_ends
        print(key, "digail ends", d_ends, "starts", d_starts, "| mimicgen", mg, "| grasp oracle",
              grasp_indices[i].tolist(), "| annotate_subtasks-equal", annot)

result = {
    "pass": bool(ok_plus1),
    "criterion": "MimicGen's parsed end of each non-final sub-task == digail's segment end + 1 (the first step the "
                 "signal is 1 is digail's end, and MimicGen puts that step into the ended sub-task, as it does for "
                 "signals its own annotate_subtasks.py writes); final sub-task end == T == digail's end; digail's "
                 "signals equal annotate_subtasks.py's output for digail's ends; same indices as the fixture's "
                 "MimicGen-style oracle `grasp`",
    "mimicgen_end_equals_digail_end_literally": bool(ok_equal),
    "export_as_is": raw,
    "demos": per_demo,
}
# 5. exports whose codes recur, and a robosuite export, parsed with the spec each announced
plans = {"recurring_codes": check_plan("recurring", OUT / "recurring-robomimic.hdf5", OUT / "recurring.plan.json")}
if (OUT / "robosuite.plan.json").exists() and "--robosuite-export" in sys.argv:
    robosuite_file = Path(json.loads((OUT / "robosuite.plan.json").read_text())["file"])
    plans["robosuite_export"] = check_plan("robosuite", robosuite_file, OUT / "robosuite.plan.json")
result["plans"] = plans
ok_all = ok_plus1 and all(p["pass"] for p in plans.values())
record = {
    "mimicgen_commit": MG_COMMIT,
    "function": "mimicgen.utils.file_utils.parse_source_dataset (with get_all_demos_from_dataset for demo_keys)",
    "call": {"subtask_term_signals": term_signals, "subtask_term_offset_ranges": offsets},
    "how_run": HOW,
    "stubs": "none (no import stubbed; mimicgen/__init__.py catches ImportError for robosuite, prints a warning). "
             "Harness: a copy of the export with placeholder datagen_info/eef_pose, target_pose (identity 4x4 per "
             "step), gripper_action (actions[:, -1:]) and an empty object_poses group, which parse_source_dataset "
             "reads unconditionally; subtask_term_signals untouched",
    "file": {"export": str(EXPORT), "harness_copy": str(HARNESS),
             "from": "tests/data/formats/robomimic_robosuite.hdf5, codes = fixture phases, names reach carry"},
    "environment": {"python": sys.version.split()[0], "robomimic": __import__("robomimic").__version__,
                    "h5py": h5py.__version__, "numpy": np.__version__},
    "result": result,
}
(OUT / "mimicgen.check.json").write_text(json.dumps(record, indent=1) + "\n")
print("PASS" if ok_all else "FAIL", "| literal equality of ends:", ok_equal, "|",
      {k: p["pass"] for k, p in plans.items()})
sys.exit(0 if ok_all else 1)
