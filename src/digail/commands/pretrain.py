"""`digail pretrain --demos D`: pre-train the VAE and write its run folder."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from digail.config import VAEConfig, check_at_least, check_codes, check_seed
from digail.errors import UserError
from digail.preset import preset_name


@dataclass(frozen=True)
class PretrainArgs:
    """Pre-train the VAE (macro-policy q, prior p, sub-task policy pi) on demonstrations."""

    demos: str
    """Minari dataset folder or id"""
    demos_episodes: int | None = None
    """use only the first N demonstrations (None: all)"""
    demos_subsample: int = 1
    """keep every K-th transition of each demonstration, from a random offset per episode drawn from the seed
    (GAIL's and DAC's few-demonstration setting: 20); 1 keeps all"""
    codes: int | Literal["auto"] | None = None
    """number of sub-task codes K, 1 to 256 (default: the preset's); `auto` tries K = 2 .. `max_codes` and keeps the one
    whose segmentation describes held-out demonstrations in the fewest nats (no labels; the curve is written to
    config.json as `k_selection`)"""
    max_codes: int = 8
    """largest K that `--codes auto` tries (at most 256, as --codes)"""
    preset: str | None = None
    """settings preset (default: the one for the dataset's env)"""
    out: Path | None = None
    """run folder (default: runs/<env>__vae__s<seed>__<time>)"""
    seed: int = 0
    """random seed"""
    device: str = "auto"
    """torch device: auto, cpu or cuda"""
    force: bool = False
    """overwrite an existing run folder"""
    vae: VAEConfig = field(default_factory=VAEConfig)
    """VAE settings (start from the preset)"""

    def __post_init__(self) -> None:
        check_seed(self.seed)
        check_at_least(self.demos_episodes, "--demos-episodes")
        check_at_least(self.demos_subsample, "--demos-subsample")
        if self.codes != "auto" and self.codes is not None:
            check_codes(self.codes)
        check_at_least(self.max_codes, "--max-codes", 2)
        check_codes(self.max_codes, "--max-codes")


def defaults(argv: Sequence[str]) -> PretrainArgs:
    """Defaults whose VAE settings start from the preset the command line asks for."""
    from digail.commands.common import preset_from_argv

    preset, _, demos = preset_from_argv(argv)
    return PretrainArgs(demos=demos, vae=preset.vae)


def pretrain_command(args: PretrainArgs) -> Path:
    """Load demonstrations, pre-train, write the run folder; returns its path.

    The run folder (written atomically: nothing is left on error) holds `model.pt`, `config.json` (the resolved
    settings with `demos`, `env_id`, `seed`), `losses.csv`, and the segmentation of the training demonstrations
    (`codes.npz`, `segmentation.json`, `figures/segmentation.png`).
    """
    from digail.algos.model_selection import check_selectable
    from digail.algos.vae_pretrain import auto_epochs, pretrain, select_codes
    from digail.checkpoint import run_config, save_model, write_run_config
    from digail.commands.common import inputs, new_run_dir
    from digail.data.minari_io import load_dataset
    from digail.data.validation import check_dataset_env
    from digail.envs.registry import env_preset, init_pieces_fn
    from digail.eval.segmentation import summary_line, write_segmentation
    from digail.fsio import atomic_dir
    from digail.nets.policy import ActionSpec
    from digail.utils import set_torch_threads
    from digail.viz.figures import codes_curve

    set_torch_threads(1)
    if not args.demos:
        raise UserError("the flag --demos is missing; pass a Minari dataset folder or id.")
    dataset = load_dataset(args.demos)
    if args.demos_episodes is not None or args.demos_subsample != 1:
        from digail.data.subset import select_demos

        dataset = dataclasses.replace(dataset, trajs=select_demos(dataset.trajs, args.demos_episodes,
                                                                  args.demos_subsample, args.seed))
    env_note = check_dataset_env(dataset)  # refuses data that does not fit its env, as `digail train` does
    if args.codes == "auto":
        check_selectable(len(dataset.trajs))
    env_id = dataset.env_id or "unknown-env"
    cfg = args.vae
    if args.preset is not None:
        preset_name(args.preset, env_preset(dataset.env_id))  # reports an unknown preset name
    if isinstance(args.codes, int):
        cfg = dataclasses.replace(cfg, codes=args.codes)
    run = new_run_dir(args.out, env_id, "vae", args.seed, args.force, reads=inputs(args.demos))
    action_spec = ActionSpec.from_space(dataset.action_space) if dataset.action_space is not None else None
    config = run_config(kind="vae", env_id=dataset.env_id, demos=args.demos, seed=args.seed, preset=args.preset,
                        device=args.device, vae=cfg, args=args, dataset_id=dataset.dataset_id)
    demos_ref = config["demos"]
    candidates = list(range(2, args.max_codes + 1)) if args.codes == "auto" else None
    if env_note is not None:
        print(f"note: {env_note}")
    restarts = f", best of {cfg.restarts} restarts" if cfg.restarts > 1 else ""
    print(f"pre-training the VAE on {len(dataset.trajs)} demonstrations of {env_id} "
          f"(K = {'auto: ' + ', '.join(map(str, candidates)) if candidates else cfg.codes}, "
          f"{auto_epochs(cfg, len(dataset.trajs))} epochs{restarts})")
    with atomic_dir(run, force=args.force) as tmp:
        started = time.perf_counter()
        restart_log: list[dict[str, float]] = []
        if candidates:
            model, _, curve = select_codes(dataset.trajs, cfg, candidates, action_spec=action_spec, seed=args.seed,
                                           device=args.device, log_dir=tmp, pieces=init_pieces_fn(dataset.env_id))
            config["k_selection"] = curve
            config["vae"]["codes"] = model.codes
            codes_curve({"--codes auto: the K curve": curve}, tmp / "figures" / "k_curve.png")
            print("K selection (held-out description length, nats per step; lower is better): "
                  + ", ".join(f"K={c['codes']}: {c['dl_per_step']:.4f}" + _use_note(c, cfg.k_count) for c in curve)
                  + f" -> K = {model.codes}")
        else:
            model, _ = pretrain(dataset.trajs, cfg, action_spec=action_spec, seed=args.seed, device=args.device,
                                log_dir=tmp, restart_log=restart_log, pieces=init_pieces_fn(dataset.env_id))
        if restart_log:
            config["restarts"] = restart_log
            chosen = min(restart_log, key=lambda r: r["dl_per_step"])
            print("restarts (held-out description length, nats per step): "
                  + ", ".join(f"seed {int(r['seed'])}: {r['dl_per_step']:.4f}" for r in restart_log)
                  + f" -> seed {int(chosen['seed'])}")
        config["vae"]["epochs_run"] = auto_epochs(cfg, len(dataset.trajs))
        config["train_time_s"] = round(time.perf_counter() - started, 2)
        save_model(tmp / "model.pt", model, kind="vae", config=config, env_id=dataset.env_id)
        write_run_config(tmp, config)
        metrics = write_segmentation(tmp, model, dataset.trajs, demos=demos_ref)
    print(summary_line(metrics))
    print(f"VAE run folder: {run}")
    return run


def _use_note(entry: dict[str, Any], count: str) -> str:
    """What the K curve's printed line says of one fit beside its description length."""
    if count == "used":
        uses = f" (uses {entry['used']} alike)" if entry.get("used", entry["codes"]) != entry["codes"] else ""
        return uses + ("" if entry.get("weighed", True) else " (not weighed)")
    return "" if entry.get("weighed", True) else " (codes used unevenly)"
