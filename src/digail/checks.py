"""The value checks every command shares: seeds, counts, the number of codes, and the numbers of a config.

Each raises the one-sentence `UserError` naming the flag, so a bad value stops a command before any work.
"""

from __future__ import annotations

from typing import Any

from digail.errors import UserError


def _require(ok: bool, flag: str, rule: str, value: Any) -> None:
    """Raise the one-sentence `UserError` naming `flag` unless `ok` (configs check their numbers on creation, so a
    bad override stops the command before any work, whichever way the config was made)."""
    if not ok:
        raise UserError(f"{flag} must be {rule}, got {value!r}.")


SEED_MAX = 2**32 - 1
"""largest seed: NumPy's legacy seeding and many environments take 32-bit seeds"""


def check_seed(seed: int, flag: str = "--seed", count: int = 1, count_flag: str = "--episodes") -> None:
    """A seed in 0..2**32-1; with `count` consecutive per-episode seeds (`count_flag`), the last one too."""
    if isinstance(count, int) and count > SEED_MAX + 1:  # no seed could start them: say what is too many
        raise UserError(f"{count_flag} must be at most {SEED_MAX + 1} (each episode has a seed of its own, and there "
                        f"are no more), got {count}.")
    _require(isinstance(seed, int) and 0 <= seed <= SEED_MAX - max(count - 1, 0), flag,
             f"between 0 and {SEED_MAX - max(count - 1, 0)}" + (f" (episode i uses {flag.lstrip('-')} + i)"
                                                                  if count > 1 else ""), seed)


EPISODES_MAX = 10**6
"""most episodes of one `digail demos`, `evaluate`, `compose` or `run` (as `--train.eval-episodes`): played one after
the other and each one's record kept, so a bound far above the largest default evaluation (300 episodes) keeps a
slip of the keyboard from a run that never ends"""

VIDEO_EPISODES_MAX = 100
"""most episodes of one `digail video`: every frame of every episode is held in memory until the video is written"""


def check_episodes(count: int | None, flag: str = "--episodes", high: int = EPISODES_MAX) -> None:
    """A number of episodes: 1 to `high` (None: the default applies)."""
    if count is not None:
        _require(isinstance(count, int) and not isinstance(count, bool) and count >= 1, flag, "at least 1", count)
        _require(count <= high, flag, f"at most {high:,}", count)


def check_at_least(value: int | None, flag: str, low: int = 1) -> None:
    """A count such as --episodes: at least `low` (None: the default applies)."""
    if value is not None:
        _require(isinstance(value, int) and value >= low, flag, f"at least {low}", value)


MAX_CODES = 256
"""most sub-task codes K: the prior holds K x K numbers and every step's q K, and no demonstrated task has come
near a hundred sub-tasks"""


def check_codes(codes: int, flag: str = "--codes") -> None:
    """The number of sub-task codes K: between 1 and `MAX_CODES` (`--codes`)."""
    _require(isinstance(codes, int) and not isinstance(codes, bool) and 1 <= codes <= MAX_CODES, flag,
             f"between 1 and {MAX_CODES}", codes)


AT_MOST: dict[str, int] = {
    "--vae.steps": 10**8, "--vae.batch-size": 2**16, "--vae.restarts": 1000, "--vae.polish-steps": 10**8,
    "--vae.init-steps": 10**8, "--vae.warmup-epochs": 10**6, "--vae.q-anticipate": 10**6,
    "--train.iterations": 10**8, "--train.eval-episodes": 10**6, "--train.bc-batch-size": 2**24,
    "--train.value-warmup": 10**6,
    "--train.env-workers": 1024,
    "--train.ppo.num-envs": 1024, "--train.ppo.batch-size": 2**24, "--train.ppo.epochs": 10**4,
    "--train.ppo.minibatch-size": 2**24,
    "--train.sac.num-envs": 1024, "--train.sac.steps-per-iteration": 2**24, "--train.sac.batch-size": 2**24,
    "--train.sac.learning-starts": 10**9, "--train.sac.policy-warmup": 10**9,
}
"""upper bounds of the counts that size memory, iterations or time, checked with the lower ones before any work:
far above any setting that has been useful (a batch of 16M rows, 100M iterations), low enough that a slip of the
keyboard (`--train.ppo.batch-size 10000000000`) is one sentence rather than an allocation failure or a run that
never ends. The replay buffer (`--train.sac.buffer-size`) is checked against the memory available instead."""


EPOCHS_MAX = 10**6
"""most VAE epochs (`--vae.epochs`), as the other counts of `AT_MOST`"""

HIDDEN_MAX = 2**14
"""widest hidden layer (`--vae.hidden`, `--train.hidden`, `--train.sac.hidden`): a 16,384 x 16,384 layer is 1 GiB
of float32 weights (three times that with Adam's moments), far above any network digail trains"""


def check_hidden(sizes: tuple[int, ...], flag: str) -> None:
    """Hidden layer sizes: each 1 to `HIDDEN_MAX` units, so a slip is one sentence rather than an allocation
    failure."""
    _require(all(isinstance(h, int) and not isinstance(h, bool) and 1 <= h <= HIDDEN_MAX for h in sizes), flag,
             f"sizes of 1 to {HIDDEN_MAX:,}", sizes)


FINAL_EVAL_SEED = 10_000
"""seed of the first episode of every final evaluation (episode i uses seed + i); training never uses it"""


def _finite(x: float) -> bool:
    return x == x and x not in (float("inf"), float("-inf"))


def _check_numbers(cfg: Any, prefix: str, at_least: dict[str, int], non_negative: tuple[str, ...] = (),
                   unit: tuple[str, ...] = ()) -> None:
    """Integers with a minimum, non-negative finite floats and [0, 1] fractions of config `cfg`; flags are named
    `prefix` + the field with dashes (how tyro spells them)."""
    def flag(name: str) -> str:
        return prefix + name.replace("_", "-")

    for name, low in at_least.items():
        v = getattr(cfg, name)
        high = AT_MOST.get(flag(name))
        _require(isinstance(v, int) and v >= low, flag(name), f"at least {low}", v)
        if high is not None:
            _require(v <= high, flag(name), f"at most {high:,}", v)
    for name in non_negative:
        v = getattr(cfg, name)
        if v is not None:
            _require(_finite(float(v)) and v >= 0, flag(name), "a finite number, not negative", v)
    for name in unit:
        v = getattr(cfg, name)
        _require(_finite(float(v)) and 0 <= v <= 1, flag(name), "between 0 and 1", v)


GENERIC_CAUSE = "lower the learning rate or check the demonstrations"
"""the advice of a non-finite-loss sentence when no setting stands out (`likely_cause`)"""

NONFINITE_SUSPECTS = {
    "ot": ("ot_epsilon", "ot_scale", "ot_cost", "ot_time_weight", "ot_code_penalty"),
    "disc": ("disc_lr", "disc_grad_penalty", "logits_to_reward", "disc_weight_decay", "disc_noise", "relabel_goals",
             "pu_prior"),
}
"""the reward settings (`--train.imitation.*`) that scale an optimal-transport reward, or D's loss and the reward
read from its logits: those a non-finite loss is blamed on when they were set away from their defaults"""


def likely_cause(message: str, imitation: Any) -> str:
    """The non-finite-loss sentence `message` with its generic advice (`GENERIC_CAUSE`) replaced by the reward
    settings most likely responsible: those of `NONFINITE_SUSPECTS` for the reward kind of `imitation` (an
    `ImitationConfig`) set away from their defaults. Unchanged when none was, or when the sentence gives other
    advice."""
    from dataclasses import fields

    suspects = NONFINITE_SUSPECTS["ot" if str(imitation.reward).startswith("ot") else "disc"]
    default = type(imitation)()  # the config's own defaults (its class sits above this module)
    moved = [f"--train.imitation.{f.name.replace('_', '-')} {getattr(imitation, f.name)}"
             for f in fields(imitation) if f.name in suspects
             and getattr(imitation, f.name) != getattr(default, f.name)]
    if not moved or GENERIC_CAUSE not in message:
        return message
    return message.replace(GENERIC_CAUSE, f"the likely cause is {' and '.join(moved)}, set away from the default: "
                           "try a value nearer it (or lower the learning rate)")
