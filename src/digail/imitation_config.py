"""What teaches the policy from the demonstrations (`--train.imitation.*`): the imitation reward, its terms, all of
the discriminator's settings, and the BC term's weight over training. A section of `TrainConfig`
(`TrainConfig.imitation`); the rewards themselves are `digail.algos.rewards`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Literal, get_args

from digail.errors import UserError

RewardKind = Literal["bce", "pu", "ot", "ot-subtask", "env"]
"""the reward names: `--train.imitation.reward` and `--train.imitation.terms` take them, and
`digail.algos.rewards.REWARDS` builds each (`ImitationConfig.reward` says what each is)"""

REWARD_KINDS: tuple[str, ...] = get_args(RewardKind)
"""the reward names, as a tuple"""

LOGITS_TO_REWARD = ("positive", "negative", "logit")
"""the names `--train.imitation.logits-to-reward` takes (`digail.algos.rewards.discriminator.generator_reward`)"""

DISC_UPDATES_MAX, DISC_MINIBATCH_MAX = 10**4, 2**24
"""upper bounds of D's passes per rollout and of its minibatch: far above any useful setting, low enough that a slip
of the keyboard is one sentence rather than a run that never ends"""

OT_COSTS = ("cosine", "euclidean")
"""the names `--train.imitation.ot-cost` takes (`digail.algos.rewards.ot.COSTS` has one row for each)"""

BC_SCHEDULES = ("fixed", "anneal", "qfilter")
"""the names `--train.imitation.bc-schedule` takes"""


def _check(ok: bool, field: str, rule: str, value: object) -> None:
    if not ok:
        raise UserError(f"--train.imitation.{field.replace('_', '-')} must be {rule}, got {value!r}.")


@dataclass(frozen=True)
class ImitationConfig:
    """The imitation reward (from D, by optimal transport, or a sum of terms), the discriminator's settings, and how
    the BC term's weight moves during training."""

    reward: RewardKind = "bce"
    """the imitation reward: `bce`, D trained by binary cross-entropy (GAIL's); `pu`, D trained as a
    positive-unlabeled classifier (Xu and Denil 2019: the agent's steps are unlabeled, a share `pu_prior` of them
    expert-like); `ot`, optimal transport between the agent's episode and the closest demonstrations on D's view
    (ROT, Haldar et al. 2022; no D); `ot-subtask`, the same with an agent step under code c matched to demonstration
    steps q labelled c; `env`, the env's own reward (no imitation: a baseline, or a term)"""
    terms: tuple[str, ...] = ()
    """more reward terms added to `reward`, each `name:weight` with a name `reward` takes (e.g. `env:0.1`: plus a
    tenth of the env's reward); at most one D-based and one optimal-transport reward in all"""
    logits_to_reward: Literal["positive", "negative", "logit"] = "positive"
    """D-based rewards: what a step earns from D's logit l: positive = -log(1 - D), negative = log D, logit =
    log D - log(1 - D) = l"""
    disc_updates: int = 1
    """D-based rewards, PPO learner: D's passes over each rollout"""
    disc_lr: float = 3e-4
    """D-based rewards: D's Adam learning rate"""
    disc_minibatch_size: int = 256
    """D-based rewards: samples per D gradient step (half agent, half expert)"""
    disc_grad_penalty: float | None = None
    """D-based rewards: weight of the gradient penalty (|grad D| - 1)^2 on points between agent and expert samples
    (DAC's). With a few demonstrations D otherwise tells them apart perfectly within a few iterations and its reward
    stops saying what to improve. None: 0 (none) with the PPO learner, 10 with SAC's (DAC's setting)"""
    disc_every: int = 1
    """D-based rewards, SAC learner: environment steps between D's steps (0: D is never trained)"""
    disc_obs: str = "all"
    """what D sees of the observation (and what an optimal-transport reward compares): all of it, the env's relative
    view (relations between the things in the scene, not where they are: for Fetch the object from the gripper and
    the goal from the object, no horizontal positions), or `module:function`, a view of the user's (raw observations
    (n, D) -> features (n, F), torch in and out). With a handful of demonstrations D otherwise tells them from the
    agent by the few object and goal positions they show"""
    pu_prior: float = 0.5
    """`pu`: eta, the share of the agent's steps taken as expert-like (the class prior of the positive class)"""
    disc_noise: float = 0.0
    """D-based rewards: std of Gaussian noise added to D's training inputs, agent and expert alike (goalGAIL's
    0.15), in units of D's normalised inputs; 0: none"""
    spectral_norm: bool = False
    """D-based rewards: spectral normalisation of D's layers (a Lipschitz bound, like the gradient penalty)"""
    disc_dropout: float = 0.0
    """D-based rewards: dropout after each hidden layer of D during its updates (off when it scores); 0: none"""
    disc_weight_decay: float = 0.0
    """D-based rewards: L2 weight decay of D's Adam, at most 1 (beyond, D's weights shrink faster than its loss
    can train them and its loss overflows); 0: none"""
    disc_actions: bool = True
    """D-based rewards: whether D sees the action beside the state; off, D judges states alone (as GAIfO), so it
    cannot tell the agent by how its sampled actions differ from the demonstrations' and grades only where the
    agent goes"""
    relabel_goals: int = 0
    """D-based rewards on goal-conditioned envs (Fetch): for every demonstration step, this many copies more among
    D's expert inputs, each with the goal replaced by where the demonstration's object is at a later step of the
    same demonstration, drawn uniformly (goalGAIL's expert relabelling: the expert's action also heads for that
    goal), so a few demonstrations show D many goals; at most 1000 (each copy is a row of D's expert inputs per
    demonstration step); 0: none"""
    ot_top_k: int = 1
    """`ot*`: how many of the closest demonstrations (lowest total transport cost) an episode's reward averages"""
    ot_cost: Literal["cosine", "euclidean"] = "cosine"
    """`ot*`: the distance between an agent step's features and a demonstration step's: `cosine` (ROT's: 1 - cos,
    in [0, 2]), or `euclidean`, the root-mean-square difference per feature in units of the demonstrations' spread
    (D's view is standardised on them), which grows with how far a step is from a demonstration's"""
    ot_epsilon: float = 0.05
    """`ot*`: entropic regularisation of the Sinkhorn iterations, in the cost's units: 1e-4 to 1e4 (below, cost /
    epsilon overflows the log-domain sums; above, the plan is uniform whatever the cost)"""
    ot_iterations: int = 50
    """`ot*`: Sinkhorn iterations (log domain) per episode's reward, 1 to 1000 (each is a pass over every
    demonstration; 1000 makes a training iteration some 20 times slower than the default)"""
    ot_scale: float = 1.0
    """`ot*`: the reward of an agent step is minus this times its transport cost (the cost its unit of mass
    pays), so with the cosine it lies in [-2 ot_scale, 0] whatever the episode's length; at most 1000, which keeps
    returns and the value loss finite"""
    ot_code_penalty: float = 1.0
    """`ot-subtask`: cost added where the agent's code and the demonstration step's code differ (a mismatch the
    marginals force still costs, so a sub-task the agent skips or overstays shows in its reward)"""
    ot_time_weight: float = 0.0
    """`ot*`: cost added per unit of |i / T_agent - j / T_demo|, the gap in episode time between matched steps (the
    in-order variant, as TemporalOT's mask); 0: order-free"""
    bc_schedule: Literal["fixed", "anneal", "qfilter"] = "fixed"
    """the BC term's weight over training: `fixed` (`--train.bc-weight` throughout); `anneal`, decayed linearly to
    0 over the run; `qfilter` (SAC), ROT's Q-filter: BC only on expert steps where the critics value the expert's
    action above the policy's, min Q(s, c, a_E) > min Q(s, c, pi(s, c))"""

    def __post_init__(self) -> None:
        _check(self.reward in REWARD_KINDS, "reward", "one of " + ", ".join(REWARD_KINDS), self.reward)
        self._check_terms()
        _check(self.logits_to_reward in LOGITS_TO_REWARD, "logits_to_reward", "one of " + ", ".join(LOGITS_TO_REWARD),
               self.logits_to_reward)
        for name, cap in (("disc_updates", DISC_UPDATES_MAX), ("disc_minibatch_size", DISC_MINIBATCH_MAX),
                          ("disc_every", None)):
            count, least = getattr(self, name), int(name == "disc_minibatch_size")
            _check(isinstance(count, int) and not isinstance(count, bool) and count >= least, name,
                   f"at least {least}", count)
            if cap is not None:
                _check(count <= cap, name, f"at most {cap:,}", count)
        for name in ("disc_lr", "disc_grad_penalty"):
            value = getattr(self, name)
            if value is not None:
                _check(math.isfinite(value) and value >= 0, name, "a finite number, not negative", value)
        _check(self.disc_obs in ("all", "relative") or re.fullmatch(r"[\w.]+:\w+", str(self.disc_obs)) is not None,
               "disc_obs", "all, relative or module:function", self.disc_obs)
        _check(self.ot_cost in OT_COSTS, "ot_cost", "one of " + ", ".join(OT_COSTS), self.ot_cost)
        _check(self.bc_schedule in BC_SCHEDULES, "bc_schedule", "one of " + ", ".join(BC_SCHEDULES),
               self.bc_schedule)
        _check(math.isfinite(self.pu_prior) and 0 < self.pu_prior < 1, "pu_prior", "between 0 and 1 (exclusive)",
               self.pu_prior)
        _check(math.isfinite(self.disc_dropout) and 0 <= self.disc_dropout < 1, "disc_dropout", "in [0, 1)",
               self.disc_dropout)
        for name in ("disc_noise", "disc_weight_decay", "ot_code_penalty", "ot_time_weight"):
            value = getattr(self, name)
            _check(math.isfinite(value) and value >= 0, name, "a finite number, not negative", value)
        for name in ("ot_epsilon", "ot_scale"):
            value = getattr(self, name)
            _check(math.isfinite(value) and value > 0, name, "positive", value)
        # the ranges within which the losses stay finite (measured at both ends); the bounds are the docstrings'
        for name, low, high in (("disc_weight_decay", 0, 1), ("ot_epsilon", 1e-4, 1e4), ("ot_scale", 0, 1e3)):
            value = getattr(self, name)
            _check(low <= value <= high, name, f"between {low:g} and {high:g}", value)
        _check(isinstance(self.relabel_goals, int) and not isinstance(self.relabel_goals, bool)
               and 0 <= self.relabel_goals <= 1000, "relabel_goals", "a whole number from 0 to 1000",
               self.relabel_goals)
        _check(self.relabel_goals == 0 or self.reward in ("bce", "pu"), "relabel_goals",
               "0 with an optimal-transport or env reward (it relabels D's expert inputs; use reward bce or pu)",
               self.relabel_goals)
        for name in ("ot_top_k", "ot_iterations"):
            value = getattr(self, name)
            _check(isinstance(value, int) and not isinstance(value, bool) and value >= 1, name, "at least 1", value)
        _check(self.ot_iterations <= 1000, "ot_iterations", "at most 1000", self.ot_iterations)

    def _check_terms(self) -> None:
        names: list[str] = [self.reward]
        for term in self.terms:
            name, sep, weight = str(term).partition(":")
            _check(bool(sep) and name in REWARD_KINDS, "terms", "name:weight with a name of " + ", ".join(REWARD_KINDS),
                   term)
            _check(name not in names, "terms", f"a reward named once (with --train.imitation.reward {self.reward})",
                   term)
            try:
                ok = math.isfinite(float(weight))
            except ValueError:
                ok = False
            _check(ok, "terms", "name:weight with a finite number as the weight", term)
            names.append(name)
        _check(sum(n in ("bce", "pu") for n in names) <= 1 and sum(n.startswith("ot") for n in names) <= 1, "terms",
               "at most one D-based (bce, pu) and one optimal-transport (ot, ot-subtask) reward in all", self.terms)

    @property
    def term_weights(self) -> tuple[tuple[str, float], ...]:
        """`terms` as (name, weight) pairs"""
        return tuple((name, float(weight)) for name, _, weight in (str(t).partition(":") for t in self.terms))

    @property
    def regularised(self) -> bool:
        """whether D's updates differ from plain GAIL's by a regulariser (then they run on autograd, as the PU loss
        always does)"""
        return self.disc_noise > 0 or self.spectral_norm or self.disc_dropout > 0 or self.disc_weight_decay > 0


MOVED_TRAIN_KEYS: dict[str, str] = {
    "disc_updates": "disc_updates", "disc_lr": "disc_lr", "disc_minibatch_size": "disc_minibatch_size",
    "disc_obs": "disc_obs", "reward": "logits_to_reward",
}
"""`TrainConfig` keys of older config.json files that are now `imitation`'s: old key -> its name there"""


def upgraded_train_dict(data: dict[str, Any]) -> dict[str, Any]:
    """A `TrainConfig` dict as older versions wrote it, with D's settings moved into `imitation` (where the new key
    is not set already): the top-level `disc_*` and `reward`, `sac.disc_every`, `imitation.kind` (now `reward`), and
    the two gradient penalties (`disc_grad_penalty` of PPO runs, `sac.grad_penalty` of SAC runs) as one."""
    data = dict(data)
    imitation = dict(data.get("imitation") or {})
    sac = dict(data.get("sac") or {}) if isinstance(data.get("sac"), dict) else data.get("sac")
    for old, new in MOVED_TRAIN_KEYS.items():
        if old in data:
            imitation.setdefault(new, data.pop(old))
    penalty_ppo = data.pop("disc_grad_penalty", None)
    penalty_sac = sac.pop("grad_penalty", None) if isinstance(sac, dict) else None
    penalty = penalty_sac if data.get("learner") == "sac" else penalty_ppo
    if penalty is not None:
        imitation.setdefault("disc_grad_penalty", penalty)
    if isinstance(sac, dict) and "disc_every" in sac:
        imitation.setdefault("disc_every", sac.pop("disc_every"))
    if "kind" in imitation:
        imitation.setdefault("reward", imitation.pop("kind"))
    if imitation or "imitation" in data:
        data["imitation"] = imitation
    if sac is not None:
        data["sac"] = sac
    return data
