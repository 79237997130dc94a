"""`digail pretrain --demos D`: pre-train the VAE and write its run folder."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from digail.config import VAEConfig, check_at_least, check_seed, get_preset
from digail.errors import UserError


@dataclass(frozen=True)
class PretrainArgs:
    """Pre-train the VAE (macro-policy q, prior p, sub-task policy pi) on demonstrations."""

    demos: str
    """Minari dataset folder or id"""
    codes: int | None = None
    """number of sub-task codes K (default: the preset's)"""
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
        check_at_least(self.codes, "--codes")


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
    from digail.algos.vae_pretrain import pretrain
    from digail.checkpoint import run_config, save_model, write_run_config
    from digail.commands.common import new_run_dir
    from digail.data.minari_io import load_dataset
    from digail.eval.segmentation import summary_line, write_segmentation
    from digail.nets.policy import ActionSpec
    from digail.utils import atomic_dir, set_torch_threads

    set_torch_threads(1)
    if not args.demos:
        raise UserError("the flag --demos is missing; pass a Minari dataset folder or id.")
    dataset = load_dataset(args.demos)
    env_id = dataset.env_id or "unknown-env"
    cfg = args.vae
    if args.preset is not None:
        get_preset(args.preset)  # reports an unknown preset name
    if args.codes is not None:
        if args.codes < 1:
            raise UserError(f"--codes must be at least 1, got {args.codes}.")
        cfg = dataclasses.replace(cfg, codes=args.codes)
    run = new_run_dir(args.out, env_id, "vae", args.seed, args.force)
    action_spec = ActionSpec.from_space(dataset.action_space) if dataset.action_space is not None else None
    config = run_config(kind="vae", env_id=dataset.env_id, demos=args.demos, seed=args.seed, preset=args.preset,
                        device=args.device, vae=cfg, args=args, dataset_id=dataset.dataset_id)
    demos_ref = config["demos"]
    print(f"pre-training the VAE on {len(dataset.trajs)} demonstrations of {env_id} (K = {cfg.codes}, "
          f"{cfg.epochs} epochs)")
    with atomic_dir(run, force=args.force) as tmp:
        started = time.perf_counter()
        model, _ = pretrain(dataset.trajs, cfg, action_spec=action_spec, seed=args.seed, device=args.device,
                            log_dir=tmp)
        config["train_time_s"] = round(time.perf_counter() - started, 2)
        save_model(tmp / "model.pt", model, kind="vae", config=config, env_id=dataset.env_id)
        write_run_config(tmp, config)
        metrics = write_segmentation(tmp, model, dataset.trajs, demos=demos_ref)
    print(summary_line(metrics))
    print(f"VAE run folder: {run}")
    return run
