"""The trainer and its learners: one registry, an interface kept by construction, nothing of one learner in another's
run, and the reward written once."""

from __future__ import annotations

import ast
import math
import typing
from pathlib import Path

import numpy as np
import torch

from digail.algos.learners import LEARNERS, PPOLearner, SACLearner
from digail.config import SACConfig, TrainConfig
from digail.data.trajectory import Trajectory

LEARNER_SRC = Path(__file__).resolve().parents[1] / "src" / "digail" / "algos" / "learners"


def test_every_learner_name_has_one_registry_entry():
    names = typing.get_args(typing.get_type_hints(TrainConfig)["learner"])
    assert set(names) == set(LEARNERS)


def test_learners_touch_no_private_state_but_their_own():
    """No `x._name` in the learners' source unless x is the learner itself: the trainer is used through `Host`."""
    offences = []
    for path in sorted(LEARNER_SRC.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")
                    and not (isinstance(node.value, ast.Name) and node.value.id == "self")):
                offences.append(f"{path.name}:{node.lineno} {ast.unparse(node)}")
    assert offences == []


def _demos() -> list[Trajectory]:
    rng = np.random.default_rng(0)
    return [Trajectory(obs=rng.normal(size=(21, 3)).astype(np.float32),
                       acts=rng.uniform(-2, 2, size=(20, 1)).astype(np.float32)) for _ in range(2)]


def _trainer(learner: str):
    from digail.algos.directed_info_gail import build_trainer

    cfg = TrainConfig(method="gail", learner=learner, hidden=(8,), backend="sync", anchor_weight=0.0,
                      sac=SACConfig(steps_per_iteration=20, learning_starts=10, hidden=(8,), batch_size=8))
    return build_trainer("Pendulum-v1", _demos(), cfg, vae_model=None, seed=0, run_dir=None, progress=False)


def test_a_sac_run_builds_nothing_of_ppo_and_its_checkpoint_holds_none():
    from digail.nets.critic import ValueNet

    trainer = _trainer("sac")
    try:
        assert type(trainer.learner) is SACLearner
        owned = [v for obj in (trainer, trainer.learner) for v in vars(obj).values()]
        assert not any(isinstance(v, ValueNet | PPOLearner) for v in owned)
        trainer.iterate()
        state = trainer.state_dict()
        assert state["learner"] == "sac" and "offpolicy" in state
        assert not {"value", "optimizer", "anchor_pi"} & set(state)
        # a checkpoint from before the learners had their own modules also kept PPO's keys in SAC runs: ignored
        trainer.load_state_dict({**state, "value": {}, "optimizer": {}, "anchor_pi": None})
    finally:
        trainer.close()


def test_the_reward_is_ds_plus_the_weighted_bonus_for_every_learner():
    """`GAIL.with_bonus`, the one place the bonus is added: r = r_D + lambda_1 (log q + log K with the code
    entropy)."""
    for learner in LEARNERS:
        trainer = _trainer(learner)
        try:
            trainer.cfg = TrainConfig(method="gail", learner=learner, bonus_weight=0.5, bonus_code_entropy=True)
            trainer.K = 3  # the code-entropy term counts only with more than one code
            imitation = torch.tensor([[0.0, 2.0]])
            batch = {"bonus": torch.tensor([[-1.0, -0.5]]), "rews": torch.zeros(1, 2)}
            rews, disc_rew = trainer.with_bonus(imitation, batch)
            torch.testing.assert_close(disc_rew, imitation)
            torch.testing.assert_close(rews, disc_rew + 0.5 * batch["bonus"] + 0.5 * math.log(3))
        finally:
            trainer.close()


# ------------------------------------------------------------------------------------------------ the fast switch
SRC = Path(__file__).resolve().parents[1] / "src" / "digail"


def test_private_torch_ops_live_in_one_module():
    """`torch._x` and `torch.ops.` appear in `digail.algos.fast.ops` only (the module that checks them)."""
    offences = []
    for path in sorted(SRC.rglob("*.py")):
        if path.name == "ops.py" and path.parent.name == "fast":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "torch"
                    and (node.attr == "ops" or (node.attr.startswith("_") and not node.attr.startswith("__")))):
                offences.append(f"{path.relative_to(SRC)}:{node.lineno} {ast.unparse(node)}")
    assert offences == []


def test_an_untested_torch_turns_the_fast_path_off_with_one_warning():
    import subprocess
    import sys

    code = ("import warnings, torch\nwarnings.simplefilter('always')\ntorch.__version__ = '2.99.0'\n"
            "from digail.algos import fast\nfrom digail.algos.fast import mlp, ops\nprint(fast.enabled())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
    assert out.stderr.count("fast path is off") == 1 and "2.99.0 is outside" in out.stderr, out.stderr


def test_the_trainer_reads_the_switch_once_when_it_is_built(monkeypatch):
    from digail.algos import fast

    trainer = _trainer("ppo")
    try:
        assert trainer.fast_path is fast.enabled() is True
        seen = []
        monkeypatch.setattr(trainer.learner, "iterate", lambda: seen.append(fast.enabled()) or {})
        monkeypatch.setenv("DIGAIL_REFERENCE", "1")  # too late for this trainer
        trainer.iterate()
        assert seen == [True] and not fast.enabled()
    finally:
        trainer.close()
    with fast.reference():
        trainer = _trainer("ppo")
    try:
        monkeypatch.delenv("DIGAIL_REFERENCE")
        assert trainer.fast_path is False and fast.enabled()
        monkeypatch.setattr(trainer.learner, "iterate", lambda: seen.append(fast.enabled()) or {})
        trainer.iterate()
        assert seen == [True, False]
    finally:
        trainer.close()
