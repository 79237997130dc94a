"""Record expert demonstrations as a Minari dataset (`digail demos`).

digail's own envs (and Fetch) are driven by their scripted experts (`digail.experts.scripted`), the others by
a reinforcement-learning expert (`digail.experts.rl.load_expert`, the shipped weights or `--expert PATH`).
Episode `i` is reset with seed `seed + i`, so a dataset is reproducible from its command line. Oracle labels
from `info["subtask"]` are kept when the env provides them.
"""

from __future__ import annotations

import os
import re
from collections import Counter
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from digail.data.minari_io import SUBTASK_KEY, flatten_dict_obs, load_dataset, minari_root
from digail.data.minari_write import write_dataset
from digail.data.trajectory import Trajectory
from digail.data.validation import check_matches_env
from digail.envs import make_env
from digail.envs.episodes import play_episode
from digail.envs.registry import env_spec
from digail.errors import UserError
from digail.experts import Policy, expert_for
from digail.fsio import check_new_dir
from digail.utils import progress_bar


def default_dataset_id(env_id: str) -> str:
    """Minari id for an env's expert demonstrations, e.g. Hopper-v5 -> digail/hopper/expert-v0 (a namespace other
    than digail's leads the name: metaworld/pick-place-v3 -> digail/metaworld-pick-place/expert-v0)."""
    namespace, _, name = env_id.rpartition("/")
    name = re.sub(r"-v\d+$", "", name).lower()
    if namespace and namespace != "digail":
        name = f"{namespace.lower()}-{name}"
    name = re.sub(r"[^a-z0-9_-]", "", name) or "env"
    return f"digail/{name}/expert-v0"


def _flat(obs: Any, space: gym.Space) -> np.ndarray:
    if isinstance(space, gym.spaces.Dict):
        return flatten_dict_obs({k: np.asarray(v)[None] for k, v in obs.items()}, space)[0]
    return np.asarray(obs)


def rollout_episodes(env: gym.Env, policy: Policy, episodes: int, seed: int = 0, *,
                     desc: str = "demos", progress: bool = True) -> list[Trajectory]:
    """Run `policy` for `episodes` episodes, episode `i` reset with `seed + i`, with a progress bar.

    Dict observations are stored flattened (`flatten_dict_obs`); the policy still sees the env's own
    observation. Actions are stored as given to the env (int64 for Discrete, float32 otherwise).
    """
    discrete = isinstance(env.action_space, gym.spaces.Discrete)

    def act(env: gym.Env, obs: Any) -> Any:
        action = policy(env, obs)
        return int(action) if discrete else np.asarray(action, dtype=np.float32).reshape(env.action_space.shape)

    trajs: list[Trajectory] = []
    returns: list[float] = []
    bar = progress_bar(episodes, progress, desc=desc, unit="ep")
    for i in range(episodes):
        ep = play_episode(env, act, seed + i, keep=True)
        labels = [info.get(SUBTASK_KEY) for info in ep.infos]
        trajs.append(Trajectory(
            obs=np.asarray([_flat(o, env.observation_space) for o in ep.obs], dtype=np.float32),
            acts=np.asarray(ep.acts, dtype=np.int64 if discrete else np.float32),
            rews=np.asarray(ep.rews, dtype=np.float32),
            subtasks=np.asarray(labels, dtype=np.int64) if all(lb is not None for lb in labels) else None,
            terminated=ep.terminated,
        ))
        returns.append(float(np.sum(ep.rews)))
        bar.set_postfix(ret=f"{returns[-1]:.2f}", mean=f"{np.mean(returns):.2f}", steps=ep.length, refresh=False)
        bar.update(1)
    bar.close()
    return trajs


def check_demos_memory(env: gym.Env, episodes: int) -> None:
    """Refuse, in one sentence and before the first episode, more episodes than the memory available holds: every
    episode is kept until the dataset is written, each step as its float32 observation, action, reward and label,
    and writing copies them once (an episode counted at the env's step limit; no limit, no check)."""
    from digail.utils import available_memory, human_bytes

    steps = None if env.spec is None else env.spec.max_episode_steps
    free = available_memory()
    if env.spec is None or not steps or free is None:
        return
    width = gym.spaces.flatdim(env.observation_space) + gym.spaces.flatdim(env.action_space) + 3
    need = 2 * episodes * (steps + 1) * width * 4
    if need > free:
        raise UserError(f"--episodes {episodes} of {env.spec.id} can take {human_bytes(need)} of memory (episodes of "
                        f"up to {steps} steps, all kept until the dataset is written) but {human_bytes(free)} is "
                        "available; record fewer episodes.")


def summarize_demos(trajs: list[Trajectory]) -> dict[str, Any]:
    """Return statistics and label counts (over all stored labels, T + 1 per episode) of some episodes."""
    returns = np.array([float(t.rews.sum()) if t.rews is not None else np.nan for t in trajs])
    lengths = np.array([len(t) for t in trajs])
    out: dict[str, Any] = {
        "episodes": len(trajs),
        "steps": int(lengths.sum()),
        "return_mean": float(np.mean(returns)),
        "return_std": float(np.std(returns)),
        "length_mean": float(lengths.mean()),
        "terminated": int(sum(t.terminated for t in trajs)),
    }
    if all(t.subtasks is not None for t in trajs):
        counts = Counter(int(c) for t in trajs for c in np.asarray(t.subtasks))
        out["label_counts"] = {str(k): counts[k] for k in sorted(counts)}
    return out


def record_demos(env_id: str, episodes: int | None = None, out: str | os.PathLike[str] | None = None,
                 seed: int = 0, expert: str | os.PathLike[str] | None = None, force: bool = False) -> Path:
    """Roll out an expert in `env_id` and write the episodes as a Minari dataset; return its folder.

    Args:
        env_id: a registered env id, e.g. "digail/CircleWorld-v0" or "Hopper-v5".
        episodes: number of episodes (default: the paper's size, the env's `EnvSpec.demo_episodes`).
        out: dataset folder (default: `$MINARI_DATASETS_PATH` or `~/.minari/datasets`, then the dataset id,
            e.g. `digail/circleworld/expert-v0`, so the id resolves there).
        seed: episode `i` is reset with `seed + i`.
        expert: RL expert file; when given it is used even for envs with a scripted expert. Default: the
            scripted expert where one exists, else the shipped RL expert.
        force: replace an existing dataset folder.

    Raises:
        UserError: unknown env, no default size (pass `episodes`), bad `episodes`, existing `out` without
            `force`, no expert available.
    """
    if episodes is None:
        spec = env_spec(env_id)
        if spec is None:
            raise UserError(f"no default number of episodes for {env_id}; pass --episodes N.")
        episodes = spec.demo_episodes
    if episodes < 1:
        raise UserError(f"--episodes must be at least 1, got {episodes}.")
    if seed < 0:
        raise UserError(f"--seed must be non-negative, got {seed}.")
    dataset_id = default_dataset_id(env_id)
    path = Path(out) if out is not None else minari_root() / dataset_id
    # fail before the (possibly long) rollouts; never onto or around the expert it reads
    check_new_dir(path, force, protected=[] if expert is None else [(expert, "the expert")])
    env = make_env(env_id)
    try:
        check_demos_memory(env, episodes)
        policy, kind = expert_for(env_id, None if expert is None else Path(expert))
        obs_space = env.observation_space
        flat_space = gym.spaces.flatten_space(obs_space) if isinstance(obs_space, gym.spaces.Dict) else None
        trajs = rollout_episodes(env, policy, episodes, seed, desc=f"demos {env_id}")
    finally:
        env.close()
    summary = summarize_demos(trajs)
    record = {"seed": seed, "episodes": episodes, "expert": kind,
              "expert_file": None if expert is None else str(expert), **summary}
    labels = "; oracle labels in infos['subtask']." if "label_counts" in summary else "."
    description = (f"{episodes} demonstrations of the {kind} expert in {env_id} recorded by digail, episode "
                   f"i reset with seed {seed} + i{labels}")
    seeds = [seed + i for i in range(episodes)]
    return write_dataset(trajs, path, env_id, dataset_id, force=force, seeds=seeds, description=description,
                         algorithm_name=f"{kind} expert", observation_space=flat_space,
                         extra_metadata=record)


SHIPPED_COMMAND = "digail demos {env} --episodes {episodes} --seed {seed} --out src/digail/datasets/{id}"
"""The command that made each shipped dataset (run from the repository root)."""


def build_manifest(root: Path | None = None) -> dict[str, Any]:
    """The content of `MANIFEST.json` for the datasets below a Minari root (default: the shipped root)."""
    from digail.data.minari_io import SHIPPED_ROOT

    root = SHIPPED_ROOT if root is None else Path(root)
    entries = []
    for meta in sorted(root.glob("**/data/metadata.json")):
        folder = meta.parent.parent
        ds_id = folder.relative_to(root).as_posix()
        entry = manifest_entry(folder, "")
        entry["command"] = SHIPPED_COMMAND.format(env=entry["env"], episodes=entry["episodes"],
                                                  seed=entry["seed"], id=ds_id)
        if entry.get("expert_file"):
            entry["command"] += f" --expert {entry['expert_file']}"
        else:  # the shipped expert's evaluation on 50 fresh episodes (digail/experts/weights/EXPERTS.json)
            from digail.experts.rl import shipped_expert_eval

            evaluation = shipped_expert_eval(entry["env"])
            if evaluation is not None:
                entry["expert_eval"] = evaluation
        entries.append(entry)
    about = ("Expert demonstrations shipped with digail (Minari datasets; this folder is a Minari root, so "
             "the ids resolve with MINARI_DATASETS_PATH pointing here). Returns are the undiscounted returns "
             "of the recorded episodes; label counts cover all stored labels (T + 1 per episode).")
    return {"description": about, "datasets": entries}


def manifest_entry(path_or_id: str | os.PathLike[str], command: str) -> dict[str, Any]:
    """One MANIFEST.json entry for a dataset written by `record_demos`, loaded and checked against its env."""
    ds = load_dataset(path_or_id)
    if ds.env_id is None:
        raise UserError(f"dataset {ds.path} records no environment id.")
    check_matches_env(ds, ds.env_id)
    record = ds.metadata.get("digail", {})
    data = ds.path / "data"
    entry: dict[str, Any] = {"id": ds.dataset_id, "env": ds.env_id, "seed": record.get("seed"),
                             "expert": record.get("expert"), "expert_file": record.get("expert_file"),
                             "command": command, **summarize_demos(ds.trajs),
                             "size_bytes": sum(f.stat().st_size for f in data.iterdir() if f.is_file())}
    return entry


def write_manifest(root: Path | None = None) -> Path:
    """Rewrite `MANIFEST.json` of a Minari root (default: the shipped one) after adding a dataset there."""
    from digail.data.minari_io import SHIPPED_ROOT
    from digail.fsio import write_json

    path = (SHIPPED_ROOT if root is None else Path(root)) / "MANIFEST.json"
    write_json(path, build_manifest(root))
    path.chmod(0o644)
    return path


if __name__ == "__main__":  # `python -m digail.data.demos` refreshes the shipped MANIFEST.json
    print(f"wrote {write_manifest()}")
