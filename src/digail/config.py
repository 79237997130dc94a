"""Configuration: the frozen dataclasses of every stage (the presets that fill them are `digail.preset`).

Every field is typed, defaulted and documented; tyro turns these classes into the command line, and the resolved
config is written as `config.json` into every run folder.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal

import tyro

from digail.checks import EPOCHS_MAX, _check_numbers, _finite, _require, check_hidden

# The shared value checks live in digail.checks; config offers them too, where callers have always found them.
from digail.checks import FINAL_EVAL_SEED as FINAL_EVAL_SEED
from digail.checks import SEED_MAX as SEED_MAX
from digail.checks import check_at_least as check_at_least
from digail.checks import check_codes as check_codes
from digail.checks import check_seed as check_seed
from digail.errors import UserError
from digail.imitation_config import ImitationConfig, upgraded_train_dict

CONTROLLER_RIDGE = 1e-4
"""the start's ridge for continuous actions under `init_actions auto` (`VAEConfig.start_ridge`): small enough that a
code's linear policy fits a proportional controller's gains (Meta-World's scripted experts: 10-25), which a ridge
of 1.0 halved, merging phases that steer to nearby points (docs/howto/choosing-k.md)"""


@dataclass(frozen=True)
class VAEConfig:
    """VAE pre-training (paper section 3.1 and appendix): macro-policy q, prior p, sub-task policy pi."""

    codes: Annotated[int, tyro.conf.Suppress] = 4
    """number of sub-task codes K (the command line's `--codes`)"""
    epochs: int | None = None
    """passes over the demonstrations (None: as many as give about `steps` gradient steps, so the work follows the
    number of updates rather than the size of the data)"""
    steps: int = 0
    """VAE gradient steps of a training whose `epochs` is None (0: keep the `init` start's q and pi as they are)"""
    batch_size: int = 32
    """demonstrations per gradient step"""
    lr: float = 3e-4
    """Adam learning rate"""
    hidden: tuple[int, ...] = (64, 64)
    """hidden layer sizes of every MLP"""
    kl_weight: float = 1.0
    """beta, weight of KL(q || p) per step"""
    smoothing_weight: float = 0.0
    """lambda_s, weight of the smoothing term L_s that penalises code switches (paper appendix)"""
    tau0: float = 5.0
    """initial Gumbel-softmax temperature"""
    tau_decay: float | None = None
    """k in tau_e = max(tau_min, tau0 * exp(-k * epoch)); None: k such that tau reaches tau_min half-way through
    the training, whatever its length (a fixed k leaves a short training at a high temperature)"""
    tau_min: float = 0.1
    """temperature floor"""
    hard: bool = False
    """straight-through hard one-hot samples in the forward pass"""
    bptt: bool = False
    """also backpropagate through q's previous-code input (the exact gradient of the sequential samples); the
    default stops the gradient there (faster, and less prone to collapsing onto one code)"""
    learn_prior: bool = True
    """learn the conditional prior p(c_t | c_{t-1}); False keeps it uniform (the authors' code)"""
    decoder_obs: tuple[int, int] | None = None
    """observation features [start, stop) the sub-task policy pi sees, kept in the model under the same name (None:
    all; q always sees all); e.g. (0, 26) in Four Rooms, the agent's position: with the goal in view pi needs no code"""
    entropy_weight: float = 0.0
    """bonus on the entropy of q(. | s_t, c_{t-1}) per step (keeps q from saturating early)"""
    max_grad_norm: float | None = None
    """clip the gradient norm of each step to this (None: no clipping)"""
    warmup_epochs: int = 0
    """epochs over which the KL and smoothing weights rise linearly from 0 (against collapse onto the prior); 0:
    `warmup_fraction` of the training instead"""
    warmup_fraction: float = 0.0
    """share of the training over which the KL and smoothing weights rise linearly from 0, when `warmup_epochs`
    is 0"""
    restarts: int = 1
    """VAEs trained from seeds seed .. seed + restarts - 1; with more than one, each trains without a held-out
    share of the demonstrations and the one describing those in the fewest nats is kept
    (`digail.algos.model_selection`: no labels needed)"""
    heldout_fraction: float = 0.2
    """share of the demonstrations held out to choose among restarts (and K with `--codes auto`)"""
    k_criterion: Literal["linear", "rff", "vae"] = "linear"
    """how `--codes auto` scores each K on the held-out demonstrations: `linear`, the description length under the
    hard-EM start's switching sub-task policies linear in the state (fast; the smallest K within one standard error
    of the best is kept), `rff`, the same with policies on random Fourier features of the state (smooth sub-tasks
    such as arcs take one code each, but on many state features extra codes keep paying), or `vae`, that of a whole
    VAE trained per K (lowest wins; the VAE's network policies explain the actions with too few codes where the
    state reveals the sub-task). `segment_init.heldout_codes_curve`, docs/howto/choosing-k.md"""
    k_ridge: float | None = None
    """ridge of the `linear` and `rff` criteria's sub-task policies (None: the start's, `start_ridge`)"""
    k_min_use: float = 0.5
    """`--codes auto` with the `linear` or `rff` criterion: a code counts as a sub-task only if it appears in at least
    this fraction as many fitted demonstrations as the most used code (0: every code): a code that far fewer
    demonstrations take than the others marks how those few differ (a regrasp, a slip), not a sub-task"""
    k_count: Literal["asked", "used"] = "asked"
    """what a fit of the K curve counts for (`linear`, `rff`): `asked`, the K it was asked for, weighed only when all
    its codes are used alike (`k_min_use`); `used`, the number of its codes used alike, so a fit asked for 5 codes
    that leaves one to a few demonstrations is a fit of 4 and the best fit of each count is weighed
    (`model_selection.by_codes_used`). Both find the phase count on 10 of the 16 Meta-World tasks, not the same
    ten (docs/howto/choosing-k.md)"""

    init: Literal["em", "none", "labels"] = "em"
    """first segmentation the VAE starts from: `em` fits q and pi (`init_steps`) to a hard-EM segmentation by
    switching linear sub-task policies (`digail.algos.segment_init`), `labels` to the demonstrations' own sub-task
    labels (annotated or generated data: label l is code l), `none` starts from random weights (the paper)"""
    init_variance: Literal["shared", "per-code"] = "shared"
    """`em` with continuous actions: one action variance per dimension shared by the codes, or one per code
    (`digail.algos.segment_init`)"""
    init_switch_costs: Literal["learned", "fixed"] = "learned"
    """`em`: charge each switch by a macro-policy learned from the state, and also start from every demonstration
    cut into K pieces where its actions change (`learned`), or log T + log(K - 1) nats per switch (`fixed`).
    Fixed suits an expert that waits in place before a switch (`digail.algos.segment_init`)"""
    init_pieces: Literal["steps", "env"] = "steps"
    """`em`: where the start's codes may change: at any step (`steps`, Viterbi over the switches), or only between
    the pieces the environment cuts a demonstration into (`env`, one code per piece: Four Rooms' room visits,
    `EnvSpec.init_pieces`; `segment_init.piece_em_segmentation`)"""
    init_obs: tuple[int, int] | None = None
    """`em`: observation features [start, stop) the start's linear sub-task policies see (None: all), e.g. (0, 26)
    in Four Rooms, the agent's position, so that a code is a field over the cells"""
    init_model: Literal["linear", "rff"] = "linear"
    """`em`: what a sub-task policy of the start is linear in: the normalised state (`linear`), or the state and
    random Fourier features of it (`rff`, a smooth function of the state; `segment_init.MODELS`)"""
    init_ridge: float | None = None
    """`em`: ridge on the state weights of the start's sub-task policies (large: about one constant action per
    code, as a straight leg of a course is; small: a policy that follows the state, as a proportional controller
    towards an object does). None: 1e-4 for continuous actions under `init_actions auto`, 1.0 otherwise (discrete
    actions, the Gaussian start); docs/howto/choosing-k.md"""
    init_actions: Literal["auto", "gaussian"] = "auto"
    """`em` with continuous actions: how the start's sub-task policies model each action dimension: `auto` reads
    off the demonstrations which dimensions are clipped at a bound (scored only up to it) and which take a few
    values (a gripper's command: a softmax over them), `gaussian` is a Gaussian on every dimension
    (`segment_models.ACTION_MODELS`)"""
    init_outlier_share: float = 1e-3
    """`em` with continuous actions: share of each action dimension's likelihood that is uniform over its range,
    which caps what one step no linear policy predicts can cost (`segment_init.OUTLIER_SHARE`; 0: a plain
    Gaussian)"""
    init_steps: int = 6000
    """gradient steps fitting q and pi to the `init` segmentation (Adam at `polish_lr`, cosine-decayed)"""
    polish_steps: int = 0
    """after the VAE, gradient steps of polishing on q's own causal segmentation of the demonstrations (0: none):
    pi by maximum likelihood of a_t given (s_t, c_t), q by cross-entropy against those codes on states with
    `q_noise` added. The segmentation is what the VAE found; the polish only sharpens the policies it feeds"""
    polish_lr: float = 1e-3
    """Adam learning rate of the polish (cosine-decayed to 0)"""
    q_noise: float = 0.0
    """std of Gaussian noise on q's state input during the polish, in units of each feature's std in the demos.
    Widens q's switching regions: the macro-policy then still switches when the agent comes near, not exactly
    onto, a state where the expert switched (Circle-World: back near the origin after the first circle)"""
    q_anticipate: int = 0
    """during the polish, train q to switch already on the last `q_anticipate` states before each switch of the
    segmentation (pi keeps the segmentation as it is): the macro-policy then switches when the agent passes
    near the end of a sub-task, not only exactly where the expert switched"""

    def curve_ridge(self, discrete: bool) -> float:
        """The ridge of the K curve's sub-task policies (`k_ridge`, or the start's)."""
        return self.start_ridge(discrete) if self.k_ridge is None else self.k_ridge

    def start_ridge(self, discrete: bool) -> float:
        """The ridge of the start's sub-task policies (`init_ridge`, or its default for these actions)."""
        if self.init_ridge is not None:
            return self.init_ridge
        return CONTROLLER_RIDGE if self.init_actions == "auto" and not discrete else 1.0

    def __post_init__(self) -> None:
        check_codes(self.codes)
        _check_numbers(self, "--vae.", dict(steps=0, batch_size=1, warmup_epochs=0, polish_steps=0,
                                            q_anticipate=0, restarts=1, init_steps=0),
                       ("lr", "kl_weight", "smoothing_weight", "tau_decay", "entropy_weight", "polish_lr", "init_ridge",
                        "k_ridge", "q_noise", "max_grad_norm"), ("warmup_fraction", "heldout_fraction", "k_min_use"))
        if self.epochs is not None:
            _require(isinstance(self.epochs, int) and 0 <= self.epochs <= EPOCHS_MAX, "--vae.epochs",
                     f"between 0 and {EPOCHS_MAX:,}", self.epochs)
        _require(self.init in ("em", "none", "labels"), "--vae.init", "em, labels or none", self.init)
        _require(self.init_variance in ("shared", "per-code"), "--vae.init-variance", "shared or per-code",
                 self.init_variance)
        _require(self.init_switch_costs in ("learned", "fixed"), "--vae.init-switch-costs", "learned or fixed",
                 self.init_switch_costs)
        if self.init == "none" and self.epochs is None and self.steps == 0:
            raise UserError("--vae.init none trains nothing without the VAE's own steps; add --vae.steps N (e.g. "
                            "1000) or --vae.epochs N.")
        _require(_finite(self.tau0) and self.tau0 > 0, "--vae.tau0", "positive", self.tau0)
        _require(_finite(self.tau_min) and self.tau_min > 0, "--vae.tau-min", "positive", self.tau_min)
        check_hidden(self.hidden, "--vae.hidden")
        _require(self.init_ridge is None or (_finite(self.init_ridge) and self.init_ridge > 0), "--vae.init-ridge",
                 "positive", self.init_ridge)
        _require(_finite(self.init_outlier_share) and 0 <= self.init_outlier_share < 1, "--vae.init-outlier-share",
                 "in [0, 1)", self.init_outlier_share)
        _require(self.init_pieces in ("steps", "env"), "--vae.init-pieces", "steps or env", self.init_pieces)
        _require(self.init_model in ("linear", "rff"), "--vae.init-model", "linear or rff", self.init_model)
        _require(self.init_actions in ("auto", "gaussian"), "--vae.init-actions", "auto or gaussian",
                 self.init_actions)
        _require(self.k_criterion in ("linear", "rff", "vae"), "--vae.k-criterion", "linear, rff or vae",
                 self.k_criterion)
        _require(self.k_count in ("used", "asked"), "--vae.k-count", "used or asked", self.k_count)
        if self.init_obs is not None:
            lo, hi = self.init_obs
            _require(0 <= lo < hi, "--vae.init-obs", "a range START STOP with 0 <= START < STOP", self.init_obs)
        if self.decoder_obs is not None:
            lo, hi = self.decoder_obs
            _require(0 <= lo < hi, "--vae.decoder-obs", "a range START STOP with 0 <= START < STOP",
                     self.decoder_obs)

    def warmup(self, epoch: int, epochs: int) -> float:
        """Factor in [0, 1] on the KL and smoothing weights at `epoch` of a training of `epochs` epochs."""
        length = self.warmup_epochs if self.warmup_epochs > 0 else self.warmup_fraction * epochs
        return 1.0 if length <= 0 else min(1.0, epoch / length)

    def tau(self, epoch: int, epochs: int) -> float:
        """Gumbel-softmax temperature at `epoch` of a training of `epochs` epochs."""
        import math

        k = self.tau_decay
        if k is None:
            k = math.log(self.tau0 / min(self.tau_min, self.tau0)) / max(epochs / 2, 1)
        return max(self.tau_min, self.tau0 * math.exp(-k * epoch))


@dataclass(frozen=True)
class PPOConfig:
    """Proximal policy optimisation (clip objective) with GAE."""

    num_envs: int = 8
    """parallel environments (stepped by `TrainConfig.backend`)"""
    batch_size: int = 512
    """environment steps per iteration, across all envs (paper Table 3 'batch size')"""
    epochs: int = 10
    """passes over each batch"""
    minibatch_size: int = 128
    """samples per gradient step"""
    lr: float = 3e-4
    """Adam learning rate of the value net (and of the policy unless `policy_lr` is set)"""
    policy_lr: float | None = None
    """Adam learning rate of the policy (None: `lr`); fine-tuning a precise behaviour-cloning policy wants it
    small, since Adam moves every weight by about the learning rate whatever the gradient's signal-to-noise"""
    gamma: float = 0.99
    """discount"""
    gae_lambda: float = 0.95
    """GAE lambda"""
    clip: float = 0.2
    """PPO ratio clip epsilon"""
    ent_coef: float = 0.0
    """lambda_2, entropy bonus weight"""
    vf_coef: float = 0.5
    """value-loss weight"""
    max_grad_norm: float = 0.5
    """gradient-norm clip"""
    norm_adv: bool = True
    """normalise advantages per minibatch"""
    anneal_lr: bool = False
    """decay the policy and value learning rates linearly to 0 over the training's iterations (the final policy
    then settles instead of being whatever the last noisy update left)"""
    target_kl: float | None = None
    """stop the epoch loop early once the approximate KL exceeds this (None: never)"""
    compile: bool = False
    """compile the minibatch loss and its backward with `torch.compile` (a one-off compile of some seconds that
    pays on long runs). Falls back to eager, with a warning, where this machine cannot compile"""

    def __post_init__(self) -> None:
        _check_numbers(self, "--train.ppo.", dict(num_envs=1, batch_size=1, epochs=1, minibatch_size=1),
                       ("lr", "policy_lr", "ent_coef", "vf_coef", "max_grad_norm", "target_kl"),
                       ("gamma", "gae_lambda"))
        _require(_finite(self.clip) and self.clip > 0, "--train.ppo.clip", "positive", self.clip)
        if self.minibatch_size > self.batch_size:
            raise UserError(f"--train.ppo.minibatch-size ({self.minibatch_size}) must not exceed "
                            f"--train.ppo.batch-size ({self.batch_size}).")
        if self.batch_size < self.num_envs:
            raise UserError(f"--train.ppo.batch-size ({self.batch_size}) must be at least --train.ppo.num-envs "
                            f"({self.num_envs}): one step per environment.")

    @property
    def effective_policy_lr(self) -> float:
        """the policy's Adam learning rate: `policy_lr`, or `lr` when that is None"""
        return self.lr if self.policy_lr is None else self.policy_lr

    @property
    def steps_per_env(self) -> int:
        """rollout length per env per iteration"""
        return max(1, self.batch_size // self.num_envs)


@dataclass(frozen=True)
class SACConfig:
    """Soft actor-critic (Haarnoja et al. 2018) on pi(a | s, c), with the reward relabelled on every sampled batch
    and absorbing states as in DAC (Kostrikov et al. 2019); D's schedule and penalty are `imitation`'s."""

    num_envs: int = 1
    """environments stepped together; each env step is followed by `utd` updates, so the updates of one batched
    step run back to back"""
    steps_per_iteration: int = 1000
    """environment steps (across all envs) per training iteration: `TrainConfig.iterations` times this is the
    budget, and checkpoints and evaluations count iterations"""
    buffer_size: int = 1_000_000
    """replay buffer capacity in transitions (the oldest are overwritten)"""
    batch_size: int = 256
    """transitions per critic and actor update"""
    lr: float = 3e-4
    """Adam learning rate of the critics"""
    policy_lr: float | None = None
    """Adam learning rate of the policy (None: `lr`)"""
    alpha_lr: float = 3e-4
    """Adam learning rate of the log entropy temperature"""
    gamma: float = 0.99
    """discount"""
    tau: float = 0.005
    """Polyak rate of the target critics"""
    init_alpha: float = 0.01
    """initial entropy temperature alpha (D's rewards are a fraction of a unit per step, so the entropy term starts
    small beside them)"""
    learn_alpha: bool = True
    """learn alpha so that the policy's entropy tracks `target_entropy`; False keeps `init_alpha`"""
    target_entropy: float | None = None
    """entropy the temperature steers the policy to (None: minus the number of action dimensions)"""
    learning_starts: int = 1000
    """environment steps collected (with the initial policy itself, not uniform actions: it may be the VAE's)
    before the first update"""
    policy_warmup: int = 5000
    """first updates train only the critics (and D), the policy held still: a random critic's gradient would
    otherwise undo a VAE initialisation in the first few hundred updates (on Hopper it did)"""
    utd: float = 1.0
    """update-to-data ratio: critic and actor updates per environment step"""
    absorbing: bool = False
    """absorbing states (DAC) for episodes that end by termination (not by time limit): D also judges the absorbing
    state, whose value is its reward forever, so the critic's target at a termination is that value instead of 0.
    Off by default: with the `positive` reward (a survival bonus) an untrained D values the absorbing state as
    highly as living, and the first Hopper steps learned to fall (docs/howto/few-demos.md); for the `logit` reward"""
    hidden: tuple[int, ...] = (256, 256)
    """hidden layer sizes of the twin critics (the policy and D keep `TrainConfig.hidden`)"""

    def __post_init__(self) -> None:
        _check_numbers(self, "--train.sac.", dict(num_envs=1, steps_per_iteration=1, buffer_size=1, batch_size=1,
                                                  learning_starts=0, policy_warmup=0),
                       ("lr", "policy_lr", "alpha_lr", "utd"), ("gamma", "tau"))
        _require(_finite(self.init_alpha) and self.init_alpha > 0, "--train.sac.init-alpha", "positive",
                 self.init_alpha)
        if self.target_entropy is not None:
            _require(_finite(self.target_entropy), "--train.sac.target-entropy", "a finite number",
                     self.target_entropy)
        _require(self.gamma < 1, "--train.sac.gamma", "below 1", self.gamma)
        check_hidden(self.hidden, "--train.sac.hidden")
        if self.steps_per_iteration < self.num_envs:
            raise UserError(f"--train.sac.steps-per-iteration ({self.steps_per_iteration}) must be at least "
                            f"--train.sac.num-envs ({self.num_envs}): one step per environment.")

    @property
    def effective_policy_lr(self) -> float:
        """the policy's Adam learning rate: `policy_lr`, or `lr` when that is None"""
        return self.lr if self.policy_lr is None else self.policy_lr

    @property
    def steps_per_env(self) -> int:
        """batched env steps per iteration"""
        return max(1, self.steps_per_iteration // self.num_envs)


@dataclass(frozen=True)
class TrainConfig:
    """GAIL / Directed-Info GAIL training (paper section 3 and eq. 4)."""

    method: Annotated[Literal["digail", "gail"], tyro.conf.Suppress] = "digail"
    """digail: K codes, frozen q, directed-info bonus; gail: one code, no bonus (set by `--method`)"""
    learner: Literal["ppo", "sac"] = "ppo"
    """the policy's learner: ppo (on-policy, the paper's) or sac (off-policy soft actor-critic with a replay
    buffer, `sac`: far fewer environment steps)"""
    iterations: int = 1000
    """training iterations: PPO iterations (paper Table 3 'epochs'), or `sac.steps_per_iteration` env steps each"""
    bonus_weight: float = 0.01
    """lambda_1, weight of the directed-info bonus log q(c_t | s_t, c_{t-1}) (paper Table 3 'posterior lambda')"""
    bonus_code_entropy: bool = False
    """add log K per step to the bonus: the code entropy H(c) of the paper's bound L_1 for uniform codes, a term the
    paper drops. Without it the bonus is never positive, so where falling ends the episode and the discriminator
    pays the agent almost nothing, every step costs and ending early pays"""
    replay_fraction: float = 0.5
    """share of envs whose codes replay q's segmentation of a random expert demonstration; the rest closed-loop"""
    closed_loop_codes: Literal["sample", "argmax"] = "sample"
    """closed-loop envs: sample c_t ~ q (docs/design.md) or take argmax q, what evaluation and segmentation do"""
    bc_weight: float = 0.0
    """weight of the BC / L2 term on expert (s, c_E) -> a_E (paper's Fetch experiment); 0 disables it"""
    anchor_weight: float = 0.0
    """weight of the anchor term: squared distance between pi's mean action (logits, for discrete actions) and
    the initial policy's (the VAE decoder for digail), on random states of each rollout; keeps fine-tuning from
    walking away from a precise initialisation where D's reward cannot tell (Circle-World). 0 disables it"""
    bc_batch_size: int = 256
    """expert samples per BC term evaluation"""
    q_lr: float = 0.0
    """PPO learner: learning rate of the macro-policy q during training, on -log q(c_t | s_t, c_{t-1}) of the
    rollouts' own codes (the paper's ascent of its bound L_1 in q as well as pi); 0 keeps q as pre-training left it
    (frozen, the default)"""
    shuffle_codes: bool = False
    """ablation: every code pi sees is a uniform random draw, each step (the BC term's expert codes once, the
    rollouts' afresh), so the codes carry nothing; the bonus is still log q of the drawn code"""
    value_warmup: int = 10
    """first iterations train only V and D, the policy held still: a random critic's noisy advantages would
    otherwise undo the VAE initialisation before GAIL has a useful signal"""
    min_init_log_std: float = -1.6
    """continuous actions: raise the initial policy's log-std to at least this (std 0.2) - a VAE decoder
    trained to tiny noise makes PPO's probability ratios explode on the first update"""
    init_from_vae: bool = True
    """initialise the sub-task policy from the VAE decoder"""
    zero_code_weights: bool = False
    """start the networks trained from scratch that read the code (the policy when not taken from the VAE, PPO's
    value net, SAC's critics) with zero weights on the code's one-hot inputs: they begin as one code-free network
    and learn how each code differs from its gradient (a policy from the VAE keeps the decoder's weights)"""
    hidden: tuple[int, ...] = (64, 64)
    """hidden layer sizes of policy, value and discriminator"""
    checkpoint_every: int = 25
    """iterations between checkpoints"""
    eval_every: int = 0
    """iterations between closed-loop evaluations during training (deterministic, `eval_episodes` episodes on the
    Gymnasium env, logged as `eval/*` scalars: the learning curve against env steps); 0 disables them"""
    eval_episodes: int = 5
    """episodes of each evaluation during training"""
    backend: Literal["auto", "sync", "subproc", "envpool"] = "auto"
    """vector env of the training rollouts (`digail.envs.vector`): sync steps the envs in this process, subproc in
    worker processes (same numbers as sync), envpool in envpool's C++ threads (Hopper, Walker2d and
    InvertedPendulum v5; same dynamics, its own reset noise); auto picks the fastest available for the env (the
    registry's choice: envpool, else subproc for MuJoCo, sync for the grid and circle worlds). Evaluation,
    demonstrations and experts always step Gymnasium's env"""
    env_workers: int = 0
    """worker processes (subproc) or threads (envpool) stepping the envs; 0: one per core"""
    ppo: PPOConfig = field(default_factory=PPOConfig)
    """PPO settings"""
    sac: SACConfig = field(default_factory=SACConfig)
    """soft actor-critic settings (`learner` sac)"""
    imitation: ImitationConfig = field(default_factory=ImitationConfig)
    """the imitation reward, the discriminator's settings and the BC weight's schedule (`digail.imitation_config`)"""

    def __post_init__(self) -> None:
        _check_numbers(self, "--train.", dict(iterations=1, checkpoint_every=1, eval_every=0, eval_episodes=1,
                                              bc_batch_size=1, value_warmup=0, env_workers=0),
                       ("bc_weight", "anchor_weight", "q_lr"),
                       ("replay_fraction",))
        _require(_finite(self.bonus_weight), "--train.bonus-weight", "a finite number", self.bonus_weight)
        _require(_finite(self.min_init_log_std), "--train.min-init-log-std", "a finite number",
                 self.min_init_log_std)
        check_hidden(self.hidden, "--train.hidden")
        _require(self.backend in ("auto", "sync", "subproc", "envpool"), "--train.backend",
                 "one of auto, sync, subproc, envpool", self.backend)
        _require(self.learner in ("ppo", "sac"), "--train.learner", "ppo or sac", self.learner)
        _require(self.q_lr == 0 or self.learner == "ppo", "--train.q-lr", "0 with --train.learner sac (q is trained "
                 "on PPO's rollouts only)", self.q_lr)

    @property
    def effective_disc_grad_penalty(self) -> float:
        """the weight of D's gradient penalty: `imitation.disc_grad_penalty`, or when that is None 0 with the PPO
        learner and 10 with SAC's (DAC's setting)"""
        weight = self.imitation.disc_grad_penalty
        if weight is None:
            return 10.0 if self.learner == "sac" else 0.0
        return weight


def to_dict(cfg: Any) -> dict[str, Any]:
    """A config dataclass as plain JSON-able data (tuples become lists)."""
    return dataclasses.asdict(cfg)


def from_dict(cls: type, data: dict[str, Any]) -> Any:
    """Rebuild a (possibly nested) config dataclass from `to_dict` output, ignoring unknown keys; the settings of a
    `TrainConfig` that older versions kept elsewhere are read where they are now (`upgraded_train_dict`)."""
    if cls is TrainConfig:
        data = upgraded_train_dict(data)
    kwargs: dict[str, Any] = {}
    hints = {f.name: f for f in dataclasses.fields(cls)}
    for key, value in data.items():
        if key not in hints:
            continue
        default = getattr(cls(), key) if _has_default(cls) else None
        if dataclasses.is_dataclass(default) and isinstance(value, dict):
            value = from_dict(type(default), value)
        elif isinstance(default, tuple) and isinstance(value, list):
            value = tuple(value)
        kwargs[key] = value
    return cls(**kwargs)


def _has_default(cls: type) -> bool:
    try:
        cls()
    except TypeError:
        return False
    return True
