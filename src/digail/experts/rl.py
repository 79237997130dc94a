"""Reinforcement-learning experts for the continuous-control experiments (paper section 5.3, Table 1).

The paper trained its MuJoCo experts with PPO; so do we, with Stable-Baselines3 (SB3) and observation (and
training-time reward) normalisation by `VecNormalize`. Pendulum's expert is SB3's SAC instead (`algo="sac"`,
raw observations, no `VecNormalize`). Training is resumable and checkpoints often, because it is the slowest
step of the whole project on a CPU.

Two formats live side by side:

* **Training checkpoints** (`OUT/checkpoints/step_<N>.pt` + `step_<N>.vecnormalize.npz` for PPO,
  `step_<N>.replay.npz` (the replay buffer) for SAC), used only by `--resume`: the state_dicts of every net
  and optimiser (value or Q nets included) and the counters as tensors and plain data, loaded with
  `torch.load(..., weights_only=True)`, and the running statistics and the buffer as arrays, loaded with
  `np.load(..., allow_pickle=False)`. SB3's own `.zip`/`.pkl` files are not used: they unpickle on load, so a
  file planted in the folder could run code. The model is rebuilt from its recipe and then given these.
* **Shipped experts** (`*.pt`): the deterministic actor alone, exported as a plain state_dict together with
  the observation statistics, the env id, the action bounds and the algorithm (`algo`; SAC's adds `squash`,
  a tanh-squashed mean), loaded with `torch.load(..., weights_only=True)`. They are tiny, pickle-free and
  need neither SB3 nor the training folder: `load_expert` rebuilds the actor from them. Every expert folder
  holds `expert.pt` (the latest export) and `best_expert.pt` (the best periodic evaluation); the shipped
  ones are copies of `best_expert.pt` in `digail/experts/weights/`.

Split by concept: `recipes` (an env's recipe, `RECIPES`), `actor` (the SB3-free
exported actor), `sb3` (training), `shipping`; this module keeps every public name importable from one place.
Why each recipe: docs/experiments.md#rl-experts.
"""

from digail.experts.actor import (
    ExpertActor,
    evaluate_expert,
    export_expert,
    load_expert,
    load_expert_actor,
    shipped_envs,
)
from digail.experts.recipes import (
    EXPERT_FORMAT,
    FINAL_EVAL_EPISODES,
    FINAL_EVAL_SEED,
    PERIODIC_EVAL_SEED,
    WEIGHTS_DIR,
    ExpertSpec,
    rl_expert_envs,
    safe_name,
    shipped_expert_path,
    spec_for,
)
from digail.experts.sb3 import ExpertRun, build_sb3_model, expert_command, train_expert
from digail.experts.shipping import RECORD_FILE, record_expert, ship_expert, shipped_expert_eval

__all__ = [
    "EXPERT_FORMAT", "FINAL_EVAL_EPISODES", "FINAL_EVAL_SEED", "PERIODIC_EVAL_SEED", "RECORD_FILE",
    "WEIGHTS_DIR", "ExpertActor", "ExpertRun", "ExpertSpec", "build_sb3_model", "evaluate_expert", "expert_command",
    "export_expert", "load_expert", "load_expert_actor", "record_expert", "rl_expert_envs", "safe_name", "ship_expert",
    "shipped_envs", "shipped_expert_eval", "shipped_expert_path", "spec_for", "train_expert",
]
