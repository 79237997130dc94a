"""Write the robomimic fixtures (tests/data/formats/robomimic_*.hdf5), or check an exported copy with robomimic's
own loader.

Runs in its own virtual environment, not digail's (robomimic 0.3.0 imports `six` without declaring it):

    python3.11 -m venv venv-robomimic
    venv-robomimic/bin/pip install torch==2.13.0 robomimic==0.3.0 six
    venv-robomimic/bin/python scripts/make_format_fixtures_robomimic.py                 # writes the fixtures
    venv-robomimic/bin/python scripts/make_format_fixtures_robomimic.py --check FILE --signals pick place

The fixtures hold the three episodes of `format_fixture_episodes.py`:

- `robomimic_d4rl.hdf5`: written by robomimic 0.3.0's own conversion script,
  `robomimic/scripts/conversion/convert_d4rl.py`, run unchanged on the episodes laid out as a D4RL dataset. The
  script imports `gym` and `d4rl` to fetch that dataset; neither installs beside robomimic here, so two small
  stand-in modules hand it the arrays (`gym.make(name).env.get_dataset()`), and everything in the file is the
  script's own writing (`data/demo_<n>/obs/flat`, `next_obs/flat`, actions, rewards, dones, `env_args`).
- `robomimic_robosuite.hdf5`: the layout robomimic's robosuite pipeline produces (`convert_robosuite.py`, then
  `dataset_states_to_obs.py`), which needs robosuite and MuJoCo renders to run, so this script writes it with h5py
  key for key: `obs/<key>` for robot0_eef_pos, object and an 8x8 `agentview_image`, `next_obs/<key>`, actions,
  rewards, dones, states, `env_args`, `mask/train` / `mask/valid`, plus MimicGen's hand-annotation signal
  `datagen_info/subtask_term_signals/grasp` (0 before the grasp, 1 from then on, as MimicGen's
  `annotate_subtasks.py` writes it). It is then loaded with robomimic's own `SequenceDataset` and
  `get_shape_metadata_from_dataset`, which fail on a layout they do not expect.

`--check FILE --signals NAMES` loads a copy digail exported with `SequenceDataset`, asking for
`datagen_info/subtask_term_signals/<name>` as dataset keys beside the actions, and prints each demonstration's
signals (robomimic's loader reads them; MimicGen reads the same datasets when it parses source demonstrations).
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import runpy
import shutil
import sys
import tempfile
import types
from pathlib import Path

import h5py
import numpy as np

# run as a script, so its own folder (scripts/) is already where imports look
from format_fixture_episodes import episodes

OUT = Path(__file__).resolve().parents[1] / "tests" / "data" / "formats"
ENV_NAME = "fixture-point-v0"


def d4rl_arrays() -> dict[str, np.ndarray]:
    """The episodes as D4RL stores a dataset: one row per step, `timeouts` on each episode's last step, and one
    extra row at the end (D4RL's files run on; the converter pairs each row with the next)."""
    eps = episodes()
    obs = [np.concatenate([e["eef"][:-1], e["object"][:-1, :3]], axis=1) for e in eps]
    obs.append(obs[-1][-1:])
    acts = [e["actions"] for e in eps] + [eps[-1]["actions"][-1:]]
    rews = [e["rewards"] for e in eps] + [np.zeros(1)]
    ends = [np.arange(len(e["actions"])) == len(e["actions"]) - 1 for e in eps] + [np.zeros(1, bool)]
    return {"observations": np.concatenate(obs).astype(np.float32), "actions": np.concatenate(acts),
            "rewards": np.concatenate(rews), "terminals": np.zeros(sum(len(o) for o in obs), bool),
            "timeouts": np.concatenate(ends)}


def write_d4rl_conversion() -> Path:
    import robomimic

    arrays = d4rl_arrays()

    class _Env:
        def __init__(self, name: str, **kwargs: object) -> None:
            self.env, self.name = self, name

        def get_dataset(self) -> dict[str, np.ndarray]:
            return arrays

        def close(self) -> None:
            pass

    sys.modules["gym"] = types.SimpleNamespace(make=lambda name, **kw: _Env(name, **kw))  # type: ignore[assignment]
    sys.modules["d4rl"] = types.SimpleNamespace(set_dataset_path=lambda path: None)  # type: ignore[assignment]
    script = Path(robomimic.__file__).parent / "scripts" / "conversion" / "convert_d4rl.py"
    with tempfile.TemporaryDirectory() as tmp:
        sys.argv = [str(script), "--env", ENV_NAME, "--folder", tmp]
        runpy.run_path(str(script), run_name="__main__")
        written = Path(tmp) / "d4rl" / "converted" / f"{ENV_NAME.replace('-', '_')}.hdf5"
        target = OUT / "robomimic_d4rl.hdf5"
        shutil.copyfile(written, target)
    return target


def write_robosuite_layout() -> Path:
    target = OUT / "robomimic_robosuite.hdf5"
    rng = np.random.default_rng(1)
    with h5py.File(target, "w") as f:
        data = f.create_group("data")
        total = 0
        for i, ep in enumerate(episodes()):
            n = len(ep["actions"])
            demo = data.create_group(f"demo_{i}")
            obs = {"robot0_eef_pos": ep["eef"], "object": ep["object"],
                   "agentview_image": rng.integers(0, 255, (n + 1, 8, 8, 3), dtype=np.uint8)}
            for key, value in obs.items():
                demo.create_dataset(f"obs/{key}", data=value[:-1])
                demo.create_dataset(f"next_obs/{key}", data=value[1:])
            demo.create_dataset("actions", data=ep["actions"])
            demo.create_dataset("rewards", data=ep["rewards"])
            demo.create_dataset("dones", data=(np.arange(n) == n - 1).astype(np.int64))
            demo.create_dataset("states", data=np.concatenate([ep["eef"][:-1], ep["object"][:-1]], axis=1))
            demo.attrs["num_samples"] = n
            demo.attrs["model_file"] = "<mujoco model='fixture'/>"
            grasp = np.ones(n, dtype=int)
            grasp[:int(np.argmax(ep["phase"][:n] == 1))] = 0
            demo.create_dataset("datagen_info/subtask_term_signals/grasp", data=grasp)
            total += n
        data.attrs["total"] = total
        data.attrs["env_args"] = json.dumps({"env_name": "Lift", "type": 1, "env_kwargs": {
            "robots": ["Panda"], "controller_configs": {"type": "OSC_POSE"}, "has_renderer": False}}, indent=4)
        f.create_dataset("mask/train", data=np.array(["demo_0", "demo_1"], dtype="S"))
        f.create_dataset("mask/valid", data=np.array(["demo_2"], dtype="S"))
    return target


def load_with_robomimic(path: Path, dataset_keys: tuple[str, ...]) -> dict[str, dict[str, list[float]]]:
    """Every demonstration of `path` through robomimic's `SequenceDataset` (low-dim keys and the image key)."""
    import robomimic.utils.file_utils as FileUtils
    import robomimic.utils.obs_utils as ObsUtils
    from robomimic.utils.dataset import SequenceDataset

    with h5py.File(path, "r") as f:
        keys = list(f["data/demo_0/obs"])
    images = [k for k in keys if k.endswith("image")]
    ObsUtils.initialize_obs_utils_with_obs_specs({"obs": {"low_dim": [k for k in keys if k not in images],
                                                          "rgb": images}})
    FileUtils.get_env_metadata_from_dataset(str(path))
    FileUtils.get_shape_metadata_from_dataset(str(path), all_obs_keys=keys)
    ds = SequenceDataset(hdf5_path=str(path), obs_keys=keys, dataset_keys=dataset_keys, load_next_obs=True,
                         hdf5_cache_mode=None)  # read from the file: its cache takes keys of one '/' only
    out: dict[str, dict[str, list[float]]] = {}
    for demo in ds.demos:
        start, n = ds._demo_id_to_start_indices[demo], ds._demo_id_to_demo_length[demo]
        items = [ds[i] for i in range(start, start + n)]
        out[demo] = {k: [float(np.asarray(it[k]).reshape(-1)[0]) for it in items] for k in dataset_keys}
    return out


def versions() -> dict[str, str]:
    return {name: importlib.metadata.version(name) for name in ("robomimic", "h5py", "numpy", "torch")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", type=Path, help="load this exported robomimic file with SequenceDataset")
    parser.add_argument("--signals", nargs="+", default=[], help="signal names to load with --check")
    args = parser.parse_args()
    if args.check:
        keys = ("actions", *[f"datagen_info/subtask_term_signals/{s}" for s in args.signals])
        loaded = load_with_robomimic(args.check, keys)
        print(json.dumps({"robomimic": versions()["robomimic"], "demos": len(loaded),
                          "signals": {d: {k.rsplit("/", 1)[1]: [int(v) for v in vals] for k, vals in ks.items()
                                          if k != "actions"} for d, ks in loaded.items()}}))
        return
    d4rl_file = write_d4rl_conversion()
    robosuite_file = write_robosuite_layout()
    load_with_robomimic(d4rl_file, ("actions", "rewards", "dones"))
    loaded = load_with_robomimic(robosuite_file, ("actions", "datagen_info/subtask_term_signals/grasp"))
    (OUT / "robomimic.versions.json").write_text(json.dumps(
        {"written_by": "scripts/make_format_fixtures_robomimic.py", "python": sys.version.split()[0],
         "robomimic_d4rl.hdf5": "robomimic's scripts/conversion/convert_d4rl.py",
         "robomimic_robosuite.hdf5": "h5py in robomimic's robosuite layout, loaded by robomimic's SequenceDataset",
         **versions()}, indent=2) + "\n")
    print(f"wrote {d4rl_file} and {robosuite_file} ({len(loaded)} demonstrations load in SequenceDataset) "
          f"with {versions()}")


if __name__ == "__main__":
    main()
