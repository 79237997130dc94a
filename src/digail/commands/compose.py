"""`digail compose RUN --order O | --schedule S`: the sub-task policies in an order of the user's instead of the
macro-policy's, closed loop (q says when each sub-task is over) or open loop (a code schedule)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import tyro

from digail.checks import check_episodes
from digail.config import check_at_least, check_seed
from digail.errors import UserError

DEFAULT_SCHEDULE = "1:60,0:60"
"""the schedule when neither --order nor --schedule is given (Circle-World's reversed circles)"""


@dataclass(frozen=True)
class ComposeArgs:
    """Run the sub-task policies in an order of your own instead of the learned macro-policy's."""

    run: Annotated[Path, tyro.conf.Positional]
    """run folder of a trained policy"""
    order: str | None = None
    """closed loop: the codes to run in turn, e.g. '2,0,1'; each runs until the macro-policy q says its sub-task is
    over (q's probability of leaving the running code, summed over its last --hold + 1 steps, reaches --hold - 1/2),
    then the next takes over; the last runs until the episode ends. No durations to give"""
    schedule: str | None = None
    """open loop: code:steps pairs, e.g. '1:60,0:60' (the default when --order is not given: Circle-World's
    reversed circles when code 1 is the counter-clockwise one; code ids are arbitrary, `mapping` in the run's
    segmentation.json says which code matched which sub-task)"""
    hold: int = 1
    """--order only: how many steps q must leave the running code for before the next one takes over (see
    --order; 2 or more ignores one-step flickers of q, and delays every switch by as many steps less one)"""
    fallback: Literal["length", "none"] = "length"
    """--order only: a code the demonstrations leave only by ending (q never switched away from it) has an end q
    cannot see; 'length' runs it for the median length of its demonstrated segments, 'none' until the episode
    ends"""
    demos: str | None = None
    """--order only: demonstrations whose segmentation gives --fallback's lengths (default: the run's training
    demonstrations)"""
    episodes: int = 100
    """episodes to roll out"""
    seed: int = 20_000
    """seed of the first episode"""

    def __post_init__(self) -> None:
        check_episodes(self.episodes)
        check_at_least(self.hold, "--hold")
        check_seed(self.seed, count=self.episodes)
        if self.order is not None and self.schedule is not None:
            raise UserError("--order and --schedule are two ways to give the order, so pass one of them: --order "
                            "'1,0' (q ends each sub-task) or --schedule '1:60,0:60' (you give the steps).")


def compose_command(args: ComposeArgs) -> dict[str, Any]:
    """Write RUN/compose.json and RUN/figures/compose.png; returns the summary."""
    import numpy as np

    from digail.checkpoint import load_model
    from digail.commands.common import check_output_folder, print_eval_summary, run_env_id
    from digail.eval.composition import compose, compose_order, episode_limit, parse_order, parse_schedule
    from digail.fsio import run_dir_lock, write_json
    from digail.viz.run_figures import composition_figure

    run = check_output_folder(args.run)
    with run_dir_lock(run):  # one writer per run folder
        model, meta = load_model(run / "model.pt")
        env_id = run_env_id(run, meta)
        if args.order is not None:
            order = parse_order(args.order, model.codes)
            # only codes before the last can need a length: the last runs until the episode ends anyway
            lengths = _fallback_lengths(run, model, meta, args) if args.fallback == "length" and len(order) > 1 \
                else {}
            result, eps = compose_order(model, env_id, order, args.episodes, args.seed, hold=args.hold,
                                        lengths={c: n for c, n in lengths.items() if c in order[:-1]})
            text, kind, switches = args.order, "order", result["switch_steps"]
        else:
            schedule = args.schedule if args.schedule is not None else DEFAULT_SCHEDULE
            pairs = parse_schedule(schedule, model.codes, episode_limit(env_id))
            result, eps = compose(model, env_id, pairs, args.episodes, args.seed)
            result["schedule"] = schedule
            text, kind, switches = schedule, "schedule", None
        fig = composition_figure([(np.asarray(e.obs), np.asarray(e.codes)) for e in eps],
                                 run / "figures" / "compose.png", text, switches=switches, kind=kind)
        result["figure"] = str(fig)
        write_json(run / "compose.json", result)
        print_eval_summary(result)
        if args.order is not None:
            print(f"order completed in {result['order_completed_rate']:.3f} of the episodes; mean switch steps "
                  f"{[round(s, 1) for s in result['mean_switch_steps']]}")
    return result


def _fallback_lengths(run: Path, model: Any, meta: dict[str, Any], args: ComposeArgs) -> dict[int, int]:
    """`demonstrated_lengths` of the run's (or --demos') demonstrations, segmented by the run's q."""
    from digail.algos.decode import segment_many
    from digail.checkpoint import read_config
    from digail.data.minari_io import load_dataset
    from digail.eval.composition import demonstrated_lengths

    demos = args.demos or (read_config(run) or meta.get("config") or {}).get("demos")
    if not demos:
        raise UserError(f"{run} does not record its demonstrations, which give the lengths of sub-tasks q never "
                        "ends; pass --demos, or --fallback none.")
    return demonstrated_lengths(segment_many(model, load_dataset(demos).trajs))
