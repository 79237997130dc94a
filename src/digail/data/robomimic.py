"""robomimic HDF5 files (the layout of robosuite, MimicGen, LIBERO and RoboCasa demonstrations), read and
annotated with h5py alone.

The layout: a `data` group with one group per demonstration, `data/demo_<n>`, each holding `actions` (T, A),
`obs/<key>` (T, ...) per observation key, `next_obs/<key>` (the state after each action), `rewards`, `dones` and
usually `states`; `data.attrs["env_args"]` is the environment's description (JSON), `mask/<filter key>` lists
subsets of the demonstrations. MimicGen adds `datagen_info/subtask_term_signals/<name>` per demonstration: one
flag per step, 0 until that sub-task has ended and 1 from then on.

Reading: the chosen observation keys (default: every low-dimensional key, i.e. at most one axis per step and not
uint8 images, in sorted name order) are flattened and joined in that order; image keys are skipped and said so.
The state after the last action comes from `next_obs`; without it, or where every demonstration's last `next_obs`
repeats its last state (robomimic's D4RL conversion writes that in place of the state it does not have), the
last action is dropped. robomimic's `dones`
marks every demonstration's last step, ended or not, so episodes are kept as truncated (bootstrapped). Existing
sub-task termination signals become oracle labels: the label of a step is how many signals have turned 1 by then
(each signal counts from its first 1 on); signals digail exported itself are not counted.

Writing (`write_subtask_signals`): a copy of the file, with digail's segmentation added as termination signals in
MimicGen's place; the input is never opened for writing. MimicGen needs, in every demonstration, one 0 -> 1 step
per named sub-task in one order, which codes that recur or segments that differ in number do not give: the export
fixes the order once and fits each demonstration's boundaries (`plan_subtasks`), and says what it chose.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from digail.data.input_files import as_float32, check_h5_links, h5_array, regular_file
from digail.data.subtask_plan import (
    MIN_SUBTASK_STEPS,
    merge_short,
    plan_line,
    plan_signals,
    plan_subtasks,
    settle_grasps,
)
from digail.errors import UserError
from digail.fsio import check_writable, signals_deferred, umask
from digail.utils import one_line

SIGNALS_PATH = "datagen_info/subtask_term_signals"
"""where MimicGen keeps each demonstration's sub-task termination signals (below `data/demo_<n>`)"""


def is_robomimic(path: str | Path) -> bool:
    """Whether `path` is an HDF5 file with robomimic's `data/demo_<n>` groups."""
    import h5py

    path = Path(path)
    if not path.is_file():
        return False
    try:
        with h5py.File(path, "r") as f:
            data = f.get("data")
            return isinstance(data, h5py.Group) and any(
                isinstance(k, str) and k.startswith("demo") and isinstance(data.get(k), h5py.Group) for k in data)
    except (OSError, RuntimeError, KeyError, ValueError):  # damaged: read_robomimic names it when asked
        return False


def demo_keys(data: Any) -> list[str]:
    """The demonstration groups of `data`, in robomimic's order (by the number after `demo_`)."""
    keys = [k for k in data if k.startswith("demo")]

    def number(key: str) -> tuple[int, str]:
        digits = re.sub(r"\D", "", key)
        return (int(digits) if digits else -1, key)

    return sorted(keys, key=number)


def _is_low_dim(dataset: Any) -> bool:
    import h5py

    return isinstance(dataset, h5py.Dataset) and dataset.ndim <= 2 and dataset.dtype != np.uint8


def _flat(group: Any, keys: Sequence[str], where: str) -> np.ndarray:
    parts = []
    for key in keys:
        if key not in group:
            raise UserError(f"{where} has no observation '{key}' (it has {', '.join(sorted(group))}); choose keys "
                            "every demonstration has with --obs-keys.")
        arr = h5_array(group[key], where, key)  # checked: numeric, real, stored in the file, within memory
        if arr.ndim == 0:
            raise UserError(f"{where} has '{key}' as a single number; it needs one row per step.")
        if arr.size == 0 and len(arr):  # rows of no values: nothing a policy could see
            raise UserError(f"{where} has observation '{key}' 0 values wide; choose keys that hold values with "
                            "--obs-keys.")
        parts.append(as_float32(arr.reshape(len(arr), -1), where, key))
    lengths = {len(p) for p in parts}
    if len(lengths) != 1:
        raise UserError(f"{where} has observation keys of different lengths ({sorted(lengths)} rows); every key "
                        "needs one row per step.")
    return np.concatenate(parts, axis=1)


def read_robomimic(path: str | Path, obs_keys: Sequence[str] | None = None) -> dict[str, Any]:
    """Demonstrations of a robomimic HDF5 file; see the module docstring.

    Args:
        path: the `.hdf5` file.
        obs_keys: observation keys to flatten and join, in this order (default: all low-dimensional keys, sorted).

    Returns:
        A dict with `episodes` (per demonstration its arrays, as `digail.data.importers.trajectories_from_episodes`
        takes them), `notes`, `found`, `episode_keys` (the demo group names) and `metadata` (the observation keys,
        `env_args`), which `digail.data.importers.read_demonstrations` checks and turns into an `Imported`.

    Raises:
        UserError: no demonstrations, a missing or image key asked for, arrays that do not fit together.
    """
    import h5py

    path = Path(path)
    where = str(path)
    regular_file(path, "robomimic file")  # a FIFO or a device is refused before it is opened
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise UserError(f"cannot read {where} as an HDF5 file ({one_line(exc)}); the file is damaged or not "
                        "HDF5.") from exc
    with f:
        check_h5_links(f, where)  # soft and external links (to nowhere, in a loop, to another file) refused
        try:
            return _read_demos(f, where, obs_keys)
        except UserError:
            raise
        except (OSError, RuntimeError, KeyError, ValueError, TypeError, AttributeError) as exc:  # flipped bytes
            raise UserError(f"cannot read {where} ({one_line(exc)}); the file is damaged.") from None


def _demo_group(data: Any, key: str, where: str) -> Any:
    """`data/<key>`, checked to be a demonstration group holding an `obs` group and an `actions` array."""
    import h5py

    demo = data[key]
    if not isinstance(demo, h5py.Group):
        raise UserError(f"{where}: data/{key} is an array, not a demonstration group; robomimic demonstrations are "
                        "groups holding obs/<key> and actions.")
    for part, kind in (("obs", h5py.Group), ("actions", h5py.Dataset)):
        if not isinstance(demo.get(part), kind):
            what = "lacks" if part not in demo else "has the wrong kind of"
            raise UserError(f"{where}: data/{key} {what} {part}; robomimic demonstrations hold obs/<key> and actions "
                            "(convert image-only files with robomimic's dataset_states_to_obs.py first).")
    return demo


def _last_rows_equal(demo: Any, keys: Sequence[str]) -> bool:
    """Whether the demonstration's last `next_obs` row repeats its last `obs` row in every key both have."""
    for c in keys:
        if c in demo["obs"] and c in demo["next_obs"]:
            a, b = demo["obs"][c], demo["next_obs"][c]
            if not a.shape or not b.shape or not a.shape[0] or not b.shape[0] or a.dtype.kind not in "biuf" \
                    or b.dtype.kind not in "biuf" or not np.array_equal(a[-1], b[-1]):
                return False
    return True


def _read_demos(f: Any, where: str, obs_keys: Sequence[str] | None) -> dict[str, Any]:
    import h5py

    data = f.get("data")
    keys = demo_keys(data) if isinstance(data, h5py.Group) else []
    if not keys:
        raise UserError(f"{where} has no data/demo_<n> groups; it is not a robomimic file.")
    demos = {key: _demo_group(data, key, where) for key in keys}
    first = demos[keys[0]]
    available = sorted(first["obs"])
    low_dim = [k for k in available if _is_low_dim(first["obs"][k])]
    images = [k for k in available if k not in low_dim]
    if obs_keys:
        for key in obs_keys:
            if key not in available:
                raise UserError(f"{where} has no observation key '{key}'; it has {', '.join(available)}.")
            if key in images:
                raise UserError(f"{where} has '{key}' as an image ({first['obs'][key].shape[1:]} per step); "
                                f"choose low-dimensional keys: {', '.join(low_dim) or 'none'}.")
        chosen = list(obs_keys)
    else:
        chosen = low_dim
        if not chosen:
            raise UserError(f"{where} has only image observations ({', '.join(images)}); digail reads "
                            "low-dimensional keys (e.g. robot0_eef_pos, object) with --obs-keys.")
    # robomimic's D4RL conversion, having no state after an episode's last action, repeats the last state as
    # the last next_obs in every demonstration; a robot at rest at the end of a real one does that only in some
    with_steps = [k for k in keys if demos[k]["actions"].shape and demos[k]["actions"].shape[0]]
    placeholder = bool(with_steps) and all(
        isinstance(demos[k].get("next_obs"), h5py.Group) and _last_rows_equal(demos[k], chosen) for k in with_steps)
    eps, dropped, signal_names = [], 0, set()
    labels: list[np.ndarray | None] = []
    kept: list[str] = []
    for key in keys:
        demo = demos[key]
        row = f"{where}, data/{key}"
        acts = h5_array(demo["actions"], row, "actions")
        if acts.ndim == 0:
            raise UserError(f"{row} has 'actions' as a single number; robomimic stores one action row per step, "
                            "so repair or drop this demonstration.")
        if not len(acts):  # nothing to learn from; said in the notes
            continue
        obs = _flat(demo["obs"], chosen, row)
        rews = h5_array(demo["rewards"], row, "rewards").reshape(-1) if "rewards" in demo else None
        n = len(acts)
        if len(obs) != n or (rews is not None and len(rews) != n):
            raise UserError(f"{row} has {len(obs)} observations, {n} actions"
                            f"{'' if rews is None else f', {len(rews)} rewards'}; robomimic stores one of each "
                            "per step.")
        next_obs = demo.get("next_obs")
        last = _flat(next_obs, chosen, f"{row}/next_obs")[-1:] if isinstance(next_obs, h5py.Group) else None
        if last is not None and len(last) and not placeholder:
            obs = np.concatenate([obs, last])
        else:
            dropped += 1
            acts, rews = acts[:-1], None if rews is None else rews[:-1]
            obs = obs[:len(acts) + 1]
            if not len(acts):
                continue
        kept.append(key)
        signals = demo.get(SIGNALS_PATH)
        oracle = _oracle_signals(signals) if isinstance(signals, h5py.Group) else []
        if oracle:
            signal_names.update(oracle)
            ended = np.stack([np.maximum.accumulate(_signal(signals, s, row) != 0) for s in oracle]).sum(axis=0)
            step_labels = np.concatenate([ended, ended[-1:]])[:len(obs)]
            labels.append(np.pad(step_labels, (0, len(obs) - len(step_labels)), mode="edge").astype(np.int64))
        else:
            labels.append(None)
        eps.append({"where": row, "obs": obs, "acts": acts, "acts_name": "actions", "rews": rews,
                    "terminated": False})
    env_args = data.attrs.get("env_args")
    masks = sorted(f["mask"]) if isinstance(f.get("mask"), h5py.Group) else []
    if not eps:
        raise UserError(f"{where} holds no demonstration with at least one step; import longer ones.")
    notes = []
    empty = len(keys) - len(kept)
    if images:
        notes.append(f"image observations skipped: {', '.join(images)} (digail reads low-dimensional keys)")
    if dropped:
        why = ("every demonstration repeats its last state as its last next_obs (robomimic's D4RL conversion "
               "writes that for want of the next state)" if placeholder else
               f"{dropped} of {len(keys)} demonstrations store no next_obs")
        notes.append(f"{why}, so the last action of each was dropped and the demonstration kept as truncated")
    if empty:
        notes.append(f"{empty} of {len(keys)} demonstrations have no step with the state after it and were skipped")
    if all(lab is not None for lab in labels):
        for ep, lab in zip(eps, labels, strict=True):
            ep["subtasks"] = lab
        notes.append(f"oracle sub-task labels read from {SIGNALS_PATH} ({', '.join(sorted(signal_names))}): a "
                     "step's label is how many of these signals have turned 1")
    elif any(lab is not None for lab in labels):
        notes.append(f"only some demonstrations have {SIGNALS_PATH}, so no oracle labels were read")
    metadata: dict[str, Any] = {"obs_keys": chosen}
    if env_args is not None:
        text = env_args.decode(errors="replace") if isinstance(env_args, bytes) else str(env_args)
        try:
            metadata["env_args"] = json.loads(text)
        except (ValueError, RecursionError):  # kept as text: it only describes the environment
            metadata["env_args"] = text
    env_name = metadata.get("env_args", {}).get("env_name") if isinstance(metadata.get("env_args"), dict) else None
    of_env = f" of {env_name}" if env_name else ""
    filters = f"; filter keys {', '.join(masks)} ignored, all demonstrations read" if masks else ""
    found = (f"a robomimic file ({len(keys)} demonstrations data/{keys[0]} .. data/{keys[-1]}{of_env}; observation "
             f"keys {', '.join(chosen)} flattened in this order{filters})")
    return {"episodes": eps, "notes": notes, "found": found, "episode_keys": kept, "metadata": metadata}


def _signal(signals: Any, name: str, row: str) -> np.ndarray:
    """One sub-task signal of a demonstration, checked: 0 or 1 per step, so NaN never counts as "turned 1"."""
    values = h5_array(signals[name], row, f"{SIGNALS_PATH}/{name}").reshape(-1)
    if values.dtype.kind in "fc" and not np.isfinite(values).all():
        raise UserError(f"{row} has NaN or inf in {SIGNALS_PATH}/{name}; a sub-task signal is 0 or 1 per step, "
                        "so repair it or remove the signals.")
    return values


def _oracle_signals(group: Any) -> list[str]:
    """The signals of a demonstration's group that are annotations, not digail's own export (which lists its
    signals in the group's `digail_signals` attribute), sorted."""
    try:
        ours = set(json.loads(group.attrs.get("digail_signals", "[]")))
    except (TypeError, ValueError):
        ours = set()
    return sorted(k for k in group if k not in ours)


def _finger_speed(demo: Any) -> np.ndarray | None:
    """Per step, the largest speed of the gripper's finger joints (robosuite's `obs/robot0_gripper_qvel`, any
    `*gripper_qvel` key), or None without one."""
    obs = demo.get("obs")
    keys = sorted(k for k in obs if k.endswith("gripper_qvel")) if obs is not None else []
    if not keys:
        return None
    return np.abs(np.asarray(obs[keys[0]][()], np.float64).reshape(len(demo["actions"]), -1)).max(1)


def write_subtask_signals(source: str | Path, out: str | Path, episode_keys: Sequence[str],
                          codes: Sequence[np.ndarray], names: Sequence[str], *, force: bool = False,
                          notes: list[str] | None = None, reading: str = "causal") -> Path:
    """Copy the robomimic file `source` to `out` with each demonstration's codes as MimicGen termination signals:
    one boundary per sub-task in every demonstration, in one order for all (`plan_subtasks`).

    Args:
        source: the robomimic file the demonstrations were read from (only read).
        out: the annotated copy to write (atomically: a temporary sibling renamed at the end).
        episode_keys: the demo group of each entry of `codes` (as `read_robomimic` lists them).
        codes: per demonstration, one code per step read (a demonstration whose last action was dropped for want
            of a next state has one code fewer; its last step takes the code before it).
        names: one signal name per code (`datagen_info/subtask_term_signals/<name>`).
        force: replace an existing `out`.
        notes: where to append the line saying which sub-tasks, in which order, were written (`plan_line`), and one
            naming the demonstrations with a sub-task too short for MimicGen's offsets.
        reading: which reading of the segmentation the codes are (`digail.algos.decode.READINGS`), kept in each
            demonstration's signals group as the attribute `digail_reading`.

    Raises:
        UserError: `out` is the source or exists without `force`, a name already in the file, codes that do not
            fit a demonstration.
    """
    import h5py

    source, out = Path(source), Path(out)
    if out.exists() and out.resolve() == source.resolve():
        raise UserError(f"--out {out} is the input file; digail never modifies its input, choose another --out.")
    if out.exists() and not force:
        raise UserError(f"output file {out} already exists; choose another --out or pass --force.")
    check_writable(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{out.name}.", dir=out.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        shutil.copyfile(source, tmp)
        os.chmod(tmp, 0o666 & ~umask())
        with h5py.File(tmp, "r+") as f:
            data = f["data"]
            fitted = []
            for key, demo_codes in zip(episode_keys, codes, strict=True):
                n = int(data[key]["actions"].shape[0])
                demo_codes = np.asarray(demo_codes).reshape(-1)
                if len(demo_codes) == n - 1:  # the dropped last action takes the code before it
                    demo_codes = np.concatenate([demo_codes, demo_codes[-1:]])
                if len(demo_codes) != n:
                    raise UserError(f"data/{key} of {source} has {n} steps but the segmentation has "
                                    f"{len(demo_codes)}; segment the demonstrations read from this file.")
                fitted.append(demo_codes)
            plan = plan_subtasks(fitted, len(names), [f"data/{k} of {source}" for k in episode_keys])
            plan = settle_grasps(plan, [_finger_speed(data[key]) for key in episode_keys])
            plan = merge_short(plan, [len(c) for c in fitted])
            for i, (key, demo_codes) in enumerate(zip(episode_keys, fitted, strict=True)):
                group = data[key].require_group(SIGNALS_PATH)
                clash = sorted(set(names) & set(group))
                if clash:
                    raise UserError(f"data/{key} of {source} already has {SIGNALS_PATH}/{clash[0]}; choose other "
                                    "--names for the exported signals.")
                for name, signal in zip(names, plan_signals(plan, i, len(demo_codes), len(names)), strict=True):
                    group.create_dataset(name, data=signal)
                earlier = [n for n in group if n not in names and n not in _oracle_signals(group)]
                group.attrs["digail_signals"] = json.dumps(sorted([*earlier, *names]))
                group.attrs["digail_reading"] = reading
        os.replace(tmp, out)
        if notes is not None:
            notes.append(plan_line(plan, names))
            if plan.short:
                named = sorted({episode_keys[d] for d, _, _ in plan.short}, key=str)
                notes.append(f"{len(named)} of {len(fitted)} demonstrations ({', '.join(named[:5])}"
                             f"{', ...' if len(named) > 5 else ''}) have a sub-task shorter than "
                             f"{plan.min_steps} steps, which MimicGen's term offsets (up to {MIN_SUBTASK_STEPS} steps "
                             "in its task configs) can move past the next sub-task's end; its parser may refuse them")
    except BaseException:
        with signals_deferred(), contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise
    return out


OBS_KEY = "observation"
"""the one observation key of a file `write_generated` writes: the env's observation as it is (importing the file
with the default keys gives the env's observation back, column for column)"""


def write_generated(trajs: Sequence[Any], out: str | Path, env_id: str, episodes: Sequence[dict[str, Any]],
                    record: dict[str, Any]) -> Path:
    """Write generated demonstrations in robomimic's layout (module doc), atomically: a temporary sibling renamed
    at the end, so a stopped write leaves nothing at `out`.

    Each demonstration's sub-tasks become MimicGen termination signals (`subtask_<i>`: 0 while its i-th played
    segment runs, 1 from the step the next one began; the last segment ends with the demonstration and has none),
    so MimicGen's parser and `digail import` read them back as labels. `env_args` names the env (robomimic's gym type);
    `data.attrs["digail_generation"]` and each demonstration's attributes say where it came from.

    Args:
        trajs: the kept episodes (`Trajectory`).
        out: the `.hdf5` file to write; refused if it exists.
        env_id: the env they were played in.
        episodes: per episode its generation record (attempt, seed, source, segments with the step each began).
        record: the generation's summary (sources, segments, frames, rate, ...).
    """
    import h5py

    out = Path(out)
    if out.exists() or out.is_symlink():
        raise UserError(f"output {out} already exists and generate never replaces one; choose another --out.")
    check_writable(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{out.name}.", dir=out.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        with h5py.File(tmp, "w") as f:
            data = f.create_group("data")
            total = 0
            for i, (traj, ep) in enumerate(zip(trajs, episodes, strict=True)):
                demo = data.create_group(f"demo_{i}")
                n = len(traj.acts)
                obs = np.asarray(traj.obs, np.float32)
                demo.create_dataset("actions", data=np.asarray(traj.acts, np.float32))
                demo.create_dataset(f"obs/{OBS_KEY}", data=obs[:n])
                demo.create_dataset(f"next_obs/{OBS_KEY}", data=obs[1:n + 1])
                demo.create_dataset("rewards", data=np.asarray(traj.rews, np.float32).reshape(-1))
                dones = np.zeros(n, np.int64)
                dones[-1] = 1  # robomimic marks each demonstration's last step
                demo.create_dataset("dones", data=dones)
                starts = [int(s["at"]) for s in ep.get("segments", [])][1:]
                for k, at in enumerate(starts):
                    signal = np.zeros(n, np.int64)
                    signal[at:] = 1  # MimicGen's sub-task ends where its signal first reads 1: the next one's start
                    demo.create_dataset(f"{SIGNALS_PATH}/subtask_{k}", data=signal)
                demo.attrs["num_samples"] = n
                demo.attrs["digail_source"] = int(ep.get("source", -1))
                demo.attrs["digail_seed"] = int(ep.get("seed", -1))
                demo.attrs["digail_segments"] = json.dumps(ep.get("segments", []))
                total += n
            data.attrs["total"] = total
            data.attrs["env_args"] = json.dumps({"env_name": env_id, "type": 2, "env_kwargs": {}})
            data.attrs["digail_generation"] = json.dumps(record)
        os.chmod(tmp, 0o666 & ~umask())
        os.replace(tmp, out)
    except BaseException:
        with signals_deferred(), contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise
    return out
