"""`--demos-episodes` / `--demos-subsample`: the first N demonstrations, every k-th transition."""

from __future__ import annotations

import numpy as np
import pytest

from digail.data.subset import select_demos
from digail.data.trajectory import Trajectory
from digail.errors import UserError


def _demos(n: int = 3, length: int = 45) -> list[Trajectory]:
    out = []
    for i in range(n):
        obs = np.arange(length + 1, dtype=np.float32)[:, None] + 1000 * i
        out.append(Trajectory(obs=obs, acts=obs[:-1] + 0.5, rews=np.ones(length, np.float32),
                              subtasks=np.zeros(length + 1, np.int64), terminated=i == 0))
    return out


def test_first_episodes_every_kth_transition_from_a_seeded_offset():
    demos = _demos()
    sub = select_demos(demos, episodes=2, every=20, seed=3)
    assert len(sub) == 2
    for orig, s in zip(demos[:2], sub, strict=True):
        start = int(s.obs[0, 0]) % 1000
        assert 0 <= start < 20
        idx = np.arange(start, len(orig), 20)
        np.testing.assert_array_equal(s.acts[:, 0], orig.acts[idx, 0])  # each pair is one the expert made
        np.testing.assert_array_equal(s.obs[:-1, 0], orig.obs[idx, 0])
        assert s.obs[-1, 0] == orig.obs[idx[-1] + 1, 0]  # the last kept transition's own successor
        assert s.terminated == orig.terminated and len(s.subtasks) == len(s.obs)
    again = select_demos(demos, episodes=2, every=20, seed=3)
    assert all(np.array_equal(a.obs, b.obs) for a, b in zip(sub, again, strict=True))
    offsets = {int(select_demos(demos, every=20, seed=s)[0].obs[0, 0]) for s in range(8)}
    assert len(offsets) > 1  # the offset is random, not always 0
    assert select_demos(demos) == demos


@pytest.mark.parametrize("kwargs, phrase", [
    (dict(episodes=0), "--demos-episodes must be at least 1"),
    (dict(episodes=4), "more episodes than the dataset's 3"),
    (dict(every=0), "--demos-subsample must be at least 1"),
])
def test_bad_subset_is_one_user_error(kwargs, phrase):
    with pytest.raises(UserError, match=phrase):
        select_demos(_demos(), **kwargs)


def test_pretrain_refuses_more_episodes_than_the_dataset(tmp_path, capsys):
    from digail.cli import main

    out = tmp_path / "vae"
    assert main(["pretrain", "--demos", "digail/pendulum/expert-v0", "--demos-episodes", "999", "--out",
                 str(out)]) == 2
    assert "--demos-episodes 999 asks for more episodes" in capsys.readouterr().err
    assert not out.exists()


def test_sweep_passes_the_subset_to_the_vae_and_the_training():
    from pathlib import Path

    from digail.sweep.plan import plan
    from digail.sweep.spec import load_spec

    jobs = plan(load_spec(Path(__file__).parents[1] / "benchmarks" / "sweeps" / "fewdemo.toml"))
    hopper = [j for j in jobs if j.env == "Hopper-v5" and j.seed == 0]
    pretrain = [j.stages[0].argv for j in hopper if j.kind == "vae"]
    trains = {j.id: j.stages[0].argv for j in hopper if j.kind == "trial" and j.stages[0].name == "train"}
    assert sorted(a[a.index("--demos-episodes") + 1] for a in pretrain) == ["1", "4"]
    for argv in trains.values():  # every training, GAIL's too, reads the same subset as its VAE
        assert "--demos-episodes" in argv and "--demos-subsample" in argv
        if "--vae" in argv:
            vae = argv[argv.index("--vae") + 1]
            assert f"demos.episodes={argv[argv.index('--demos-episodes') + 1]}" in vae
    sac = [a for a in trains.values() if "--train.learner" in a and a[a.index("--train.learner") + 1] == "sac"]
    assert len(sac) == 4  # gail and digail, two demonstration settings
