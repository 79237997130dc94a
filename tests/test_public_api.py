"""The public API at the package top level: every name resolves to its home module's object, lazily."""

from __future__ import annotations

import importlib
import subprocess
import sys

import digail


def test_top_level_names_are_the_deep_objects():
    public = {"Trajectory", "UserError", "__version__", *digail._PUBLIC}
    assert set(digail.__all__) == public
    for name, module in digail._PUBLIC.items():
        assert getattr(digail, name) is getattr(importlib.import_module(module), name), name
    assert set(digail._PUBLIC) <= set(dir(digail))


def test_unknown_name_is_an_attribute_error():
    try:
        digail.no_such_name  # noqa: B018
    except AttributeError as err:
        assert "no_such_name" in str(err)
    else:
        raise AssertionError("digail.no_such_name resolved")


def test_import_digail_leaves_the_training_code_unimported():
    """`import digail` registers the envs and nothing more (not even torch); the first use of a name imports its
    module."""
    code = ("import sys, digail\n"
            "heavy = [m for m in ('digail.algos.vae_pretrain', 'digail.algos.directed_info_gail',"
            " 'digail.eval.returns', 'digail.data.minari_io', 'minari', 'sklearn', 'torch') if m in sys.modules]\n"
            "assert not heavy, heavy\n"
            "import gymnasium\n"
            "assert 'digail/CircleWorld-v0' in gymnasium.registry\n"
            "digail.pretrain\n"
            "assert 'digail.algos.vae_pretrain' in sys.modules\n")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_train_copies_the_vae_and_picks_the_method_from_it(monkeypatch):
    """`digail.train` leaves the VAE it is given as it was, and with no settings runs the env's preset as
    Directed-Info GAIL when given a VAE, as GAIL (one code) without one."""
    import torch

    from digail.config import VAEConfig
    from digail.data.minari_io import load_dataset
    from digail.envs import registry
    from digail.preset import get_preset

    monkeypatch.setattr(registry, "preset_for", lambda env_id, name=None: get_preset("smoke"))
    env_id, trajs = "digail/CircleWorld-v0", load_dataset("digail/circleworld/expert-v0").trajs[:4]
    vae, _ = digail.pretrain(trajs, VAEConfig(codes=2, init_steps=50, polish_steps=0), seed=0, progress=False)
    before = {k: v.clone() for k, v in vae.state_dict().items()}
    policy = digail.train(env_id, trajs, vae, seed=0, progress=False)
    assert policy is not vae and policy.codes == 2
    assert all(torch.equal(before[k], v) for k, v in vae.state_dict().items())
    assert any(not torch.equal(before[k], v) for k, v in policy.state_dict().items() if k.startswith("pi."))
    assert digail.train(env_id, trajs, seed=0, progress=False).codes == 1
