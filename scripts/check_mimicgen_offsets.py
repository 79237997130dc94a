"""Run MimicGen's own `parse_source_dataset` on digail's robomimic exports, one demonstration at a time, with an
offset range on every signal, and count the demonstrations it takes.

    python scripts/check_mimicgen_offsets.py --mimicgen-source MIMICGEN_CHECKOUT --offsets 10 20 \\
        --json OUT.json EXPORT.hdf5 [EXPORT.hdf5 ...]

MimicGen (NVlabs/mimicgen) is not on PyPI and its `mimicgen.utils.file_utils` imports robomimic and the Hugging Face
hub at module level, so the two functions used (`get_all_demos_from_dataset`, `parse_source_dataset`) and
`mimicgen.datagen.datagen_info.DatagenInfo` are run verbatim from the checkout's source with h5py, numpy and tqdm,
as scripts/check_mimicgen_signals.py does. The parser reads the demonstrations' poses unconditionally; a copy of
each export gets identity placeholders for them (the signals untouched). The task spec is the export's signals in
the order they turn on, then None for the last sub-task. For each demonstration the parser's sanity check must pass:
every sub-task's end plus its largest offset before the next one's end plus its smallest (a demonstration that
fails is listed with MimicGen's message).
"""
import argparse
import json
import shutil
import tempfile
from pathlib import Path

import h5py
import numpy as np
from tqdm import tqdm


def mimicgen_functions(source: Path) -> dict:
    info: dict = {}
    exec(compile((source / "mimicgen/datagen/datagen_info.py").read_text(), "datagen_info.py", "exec"), info)
    text = (source / "mimicgen/utils/file_utils.py").read_text()
    ns = {"h5py": h5py, "np": np, "tqdm": tqdm, "DatagenInfo": info["DatagenInfo"]}
    for fn in ("get_all_demos_from_dataset", "parse_source_dataset"):
        start = text.index(f"def {fn}(")
        end = text.index("\ndef ", start + 1)
        exec(compile(text[start:end], "mimicgen/utils/file_utils.py", "exec"), ns)
    return ns


def with_placeholder_poses(export: Path, copy: Path) -> Path:
    shutil.copyfile(export, copy)
    with h5py.File(copy, "r+") as f:
        for key in f["data"]:
            demo = f[f"data/{key}"]
            steps = demo["actions"].shape[0]
            dg = demo["datagen_info"]
            for name, data in (("eef_pose", np.tile(np.eye(4), (steps, 1, 1))),
                               ("target_pose", np.tile(np.eye(4), (steps, 1, 1))),
                               ("gripper_action", demo["actions"][:, -1:])):
                if name not in dg:
                    dg.create_dataset(name, data=data)
            if "object_poses" not in dg:
                dg.create_group("object_poses")
    return copy


def check(mg: dict, export: Path, offsets: tuple[int, int], tmp: Path) -> dict:
    path = with_placeholder_poses(export, tmp / "harness.hdf5")
    keys = mg["get_all_demos_from_dataset"](dataset_path=str(path))
    with h5py.File(path, "r") as f:
        sig = f[f"data/{keys[0]}/datagen_info/subtask_term_signals"]
        first = {n: int(np.flatnonzero(np.diff(np.r_[0, sig[n][()]]) > 0)[0]) for n in sig if sig[n][()].any()}
    names = sorted(first, key=first.get)
    failed = []
    for key in keys:
        try:
            mg["parse_source_dataset"](dataset_path=str(path), demo_keys=[key], subtask_term_signals=[*names, None],
                                       subtask_term_offset_ranges=[tuple(offsets)] * len(names) + [(0, 0)])
        except AssertionError as e:
            failed.append({"demo": key, "mimicgen": str(e)})
    return {"export": str(export), "task_spec": [*names, None], "offsets": list(offsets),
            "passed": len(keys) - len(failed), "demonstrations": len(keys), "failed": failed}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("exports", nargs="+", type=Path)
    parser.add_argument("--mimicgen-source", type=Path, required=True)
    parser.add_argument("--offsets", nargs=2, type=int, default=[10, 20])
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    mg = mimicgen_functions(args.mimicgen_source)
    with tempfile.TemporaryDirectory() as tmp:
        results = [check(mg, e, tuple(args.offsets), Path(tmp)) for e in args.exports]
    for r in results:
        print(f"{r['export']}: {r['passed']} of {r['demonstrations']} taken with offsets {r['offsets']}")
    if args.json:
        args.json.write_text(json.dumps({"mimicgen": "NVlabs/mimicgen 72bd767 (mimicgen/utils/file_utils.py)",
                                         "command": "python scripts/check_mimicgen_offsets.py " + " ".join(
                                             [*map(str, args.exports), "--mimicgen-source", "MIMICGEN_CHECKOUT",
                                              "--offsets", *map(str, args.offsets)]),
                                         "results": results}, indent=1) + "\n")


if __name__ == "__main__":
    main()
