"""The segmentation benchmark's fast subset: waypoint courses recorded with Minari's API, segmented by
`digail pretrain` with the defaults; the hard-EM start; restarts and K chosen without labels."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

from digail.algos.model_selection import description_length, heldout_split
from digail.algos.segment_init import hard_em_segmentation
from digail.algos.vae_pretrain import pretrain, select_codes
from digail.config import VAEConfig
from digail.data.courses import record_course
from digail.data.minari_io import load_dataset
from digail.envs.waypoints import COURSES
from digail.eval.segmentation import segmentation_metrics


@pytest.fixture(scope="module")
def minari_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("minari")


def _labels(trajs: list) -> list[np.ndarray]:
    return [np.asarray(t.subtasks) for t in trajs]


def test_courses_record_oracle_labels_through_minari(minari_root: Path) -> None:
    ds = load_dataset(record_course("shuttle-repeat", minari_root, seed=0, episodes=3))
    assert ds.env_id == "digail/WaypointCourse-v0" and len(ds.trajs) == 3 and ds.has_labels
    for t in ds.trajs:
        assert list(np.unique(t.subtasks)) == [0, 1] and np.count_nonzero(np.diff(t.subtasks)) == 3
        assert t.terminated


@pytest.mark.parametrize("name", ["shuttle", "grid-six"])
def test_hard_em_start_finds_the_sub_tasks_the_actions_reveal(name: str, minari_root: Path) -> None:
    """shuttle: perfect. grid-six: two "right" and two "up" legs, 10% random actions. With a fixed cost per
    switch, one code for "right, then up" is cheaper than two legs (measured 0.595 on these 8 episodes); learned
    switch costs from the ordered start keep the legs apart (0.977)."""
    ds = load_dataset(record_course(name, minari_root, seed=0, episodes=8))
    codes = hard_em_segmentation(ds.trajs, COURSES[name].codes, name.startswith("grid"), seed=0, starts=2)
    m = segmentation_metrics(codes, _labels(ds.trajs))
    assert m["accuracy"] >= (0.99 if name == "shuttle" else 0.95)
    if name == "grid-six":
        fixed = hard_em_segmentation(ds.trajs, 6, True, seed=0, starts=2, switch_costs="fixed")
        assert segmentation_metrics(fixed, _labels(ds.trajs))["accuracy"] < 0.7


def test_ordered_pieces_cut_where_the_actions_change() -> None:
    """The exact least-squares cut into K consecutive pieces, codes in time order; fewer steps than K: one piece
    per step."""
    from digail.algos.segment_search import _ordered_pieces

    rng = np.random.default_rng(0)
    means = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])
    truth = np.repeat([0, 1, 2], [7, 15, 4])
    feat = means[truth] + 0.1 * rng.normal(size=(len(truth), 2))
    np.testing.assert_array_equal(_ordered_pieces(feat, 3), truth)
    np.testing.assert_array_equal(_ordered_pieces(feat[:2], 3), [0, 1])


def test_hard_em_splits_by_policy_not_by_how_exactly_actions_are_predicted() -> None:
    """Two sub-tasks, each a saturating proportional controller that drives to its goal (+1, then -1) and then
    holds still there, as Fetch's pick and place do. Holding still is predicted almost exactly by either policy;
    with a variance per code, a code of those steps earned a density bonus and the start split holding from
    moving (measured: accuracy 0.62, 2 switches per episode); with one variance shared by the codes it splits
    the two controllers. Fixed switch costs: the switch here comes after a hold, where the state does not announce
    it, and learned costs prefer a cut the state announces (measured 0.632; docs/experiments.md)."""
    from digail.data.trajectory import Trajectory

    rng = np.random.default_rng(0)
    trajs = []
    for _ in range(20):
        pos = -1 + 0.1 * rng.normal()
        obs, acts = [pos], []
        for t in range(60):
            goal = 1.0 if t < 30 else -1.0
            act = np.clip(2.0 * (goal - pos), -1, 1) + 1e-3 * rng.normal()
            pos += 0.25 * act
            obs.append(pos)
            acts.append([act])
        trajs.append(Trajectory(obs=np.array(obs, np.float32)[:, None], acts=np.array(acts, np.float32),
                                subtasks=np.repeat([0, 1], [30, 31])))
    m = segmentation_metrics(hard_em_segmentation(trajs, 2, False, seed=0, switch_costs="fixed"), _labels(trajs))
    assert m["accuracy"] >= 0.99 and m["switches_per_episode"] == 1.0


@pytest.mark.parametrize("name", ["shuttle", "square"])
def test_pretrain_cli_with_the_defaults_segments_a_course(name: str, minari_root: Path, tmp_path: Path) -> None:
    """The benchmark's protocol on two of its tasks (fewer episodes): `digail pretrain --codes K`, defaults only."""
    from digail.cli import main

    folder = record_course(name, minari_root, seed=0, episodes=8)
    run = tmp_path / "run"
    assert main(["pretrain", "--demos", str(folder), "--codes", str(COURSES[name].codes), "--out", str(run)]) == 0
    seg = json.loads((run / "segmentation.json").read_text())
    assert seg["accuracy"] >= 0.9
    assert seg["switches_per_episode"] <= 1.5 * seg["true_switches_per_episode"]
    assert seg["switches_per_episode"] >= seg["true_switches_per_episode"] / 1.5


def test_pretrain_cli_with_the_defaults_segments_the_landmark_route(tmp_path: Path) -> None:
    """The benchmark's shipped landmark-route task on its first 10 demonstrations: `--preset default`, K = 4, every
    leg found (the touch sensor makes each switch one feature; without it q missed 10-25 % of them)."""
    from digail.cli import main

    run = tmp_path / "run"
    assert main(["pretrain", "--demos", "digail/landmarkroute/expert-v0", "--demos-episodes", "10", "--codes", "4",
                 "--preset", "default", "--out", str(run)]) == 0
    seg = json.loads((run / "segmentation.json").read_text())
    assert seg["accuracy"] >= 0.95 and seg["switches_per_episode"] == seg["true_switches_per_episode"] == 3.0


def test_description_length_charges_switches() -> None:
    train, held = heldout_split(10, 0.2, seed=0)
    assert len(held) == 2 and sorted([*train, *held]) == list(range(10))
    assert heldout_split(1, 0.2, 0)[1].tolist() == [0]


FAST = VAEConfig(init_steps=300)
"""fewer gradient steps than the defaults: these tests are about the choice among models, not their quality"""


def test_restarts_keep_the_lowest_held_out_description_length(minari_root: Path) -> None:
    ds = load_dataset(record_course("shuttle", minari_root, seed=0, episodes=8))
    log: list[dict[str, float]] = []
    cfg = dataclasses.replace(FAST, codes=2, restarts=2)
    model, _ = pretrain(ds.trajs, cfg, seed=0, progress=False, restart_log=log)
    assert [r["seed"] for r in log] == [0, 1]
    train, held = heldout_split(len(ds.trajs), cfg.heldout_fraction, 0)
    chosen = description_length(model, [ds.trajs[i] for i in held])["dl_per_step"]
    assert chosen == pytest.approx(min(r["dl_per_step"] for r in log))


def test_codes_auto_scored_by_whole_vaes_finds_the_shuttles_two(minari_root: Path) -> None:
    """`--vae.k-criterion vae`: on the shuttle (K = 2) the held-out description length is lowest at K = 2. q must
    have learnt to switch for that: with 300 steps fitting it to the start, K = 2's q never switched and K = 4 won
    (measured)."""
    ds = load_dataset(record_course("shuttle", minari_root, seed=0, episodes=8))
    cfg = dataclasses.replace(FAST, init_steps=1500, k_criterion="vae")
    model, _, curve = select_codes(ds.trajs, cfg, [2, 3], seed=0, progress=False)
    assert [c["codes"] for c in curve] == [2, 3]
    assert model.codes == 2 and [c["chosen"] for c in curve] == [True, False], curve


def test_codes_auto_scored_by_linear_policies_finds_the_squares_four(minari_root: Path) -> None:
    """The default criterion on the square (K = 4), where whole VAEs chose K = 2 (their network policy reads the
    corner from the position): linear sub-task policies need one code per leg, and past 4 the curve is flat, so
    the one-standard-error rule keeps 4."""
    ds = load_dataset(record_course("square", minari_root, seed=0))
    model, _, curve = select_codes(ds.trajs, dataclasses.replace(FAST, init_steps=300), [2, 3, 4, 5, 6], seed=0,
                                   progress=False)
    assert model.codes == 4, curve
    dl = [c["dl_per_step"] for c in curve]
    assert dl[2] < dl[1] - 1.0 and abs(dl[3] - dl[2]) < 0.05  # a clear knee at the truth, flat after it


def test_the_vae_alone_needs_training_steps() -> None:
    from digail.errors import UserError

    with pytest.raises(UserError, match="--vae.steps"):
        VAEConfig(init="none")
    assert VAEConfig(init="none", steps=10).steps == 10


def test_one_standard_error_rule_keeps_the_smallest_k_the_data_cannot_tell_from_the_best() -> None:
    from digail.algos.model_selection import smallest_within_one_se

    rng = np.random.default_rng(0)
    base = rng.normal(100.0, 10.0, 30)  # held-out episodes differ a lot; the models little
    curve = [{"codes": 2, "episode_dl": base + 30.0},
             {"codes": 3, "episode_dl": base - 0.05 + np.resize([1.0, -1.0], 30)},
             {"codes": 4, "episode_dl": base - 0.1}, {"codes": 5, "episode_dl": base - 5.0}]
    for c in curve:
        c["dl_per_step"] = float(np.mean(c["episode_dl"]))
    assert smallest_within_one_se(curve[:3]) == 1  # K = 3 is within noise of K = 4, the lowest
    assert smallest_within_one_se(curve) == 3  # K = 5 is lower by far more than its standard error
    # K = 5 leaves a code that few fitted demonstrations take: with a minimum share it is not weighed, and K = 3
    # is within noise of the lowest of those left, K = 4
    for c, share in zip(curve, (1.0, 0.9, 0.6, 0.1), strict=True):
        c["least_used"] = share
    assert smallest_within_one_se(curve, 0.5) == 1
    assert smallest_within_one_se(curve, 0.0) == 3
    assert smallest_within_one_se(curve, 0.95) == 0  # only K = 2 is left
    assert smallest_within_one_se(curve, 1.1) == 3  # none is left: all are weighed
    # what the curve records: code 2 appears in one demonstration of three, codes 0 and 1 in all three
    from digail.algos.segment_init import _least_used

    seg = [np.array([0, 0, 1]), np.array([0, 1, 1, 2]), np.array([1, 0])]
    assert _least_used(seg, 3) == pytest.approx(1 / 3) and _least_used(seg, 2) == 1.0


def test_a_fit_counts_for_the_codes_it_uses_alike() -> None:
    """Hard EM asked for 5 codes leaves one to a single demonstration and describes the held-out actions far better
    than the fit asked for 4, which merged two sub-tasks: counted by the codes it uses, that fit stands for K = 4 and
    wins; counted by what it was asked for, it is not weighed and the merged fits decide."""
    from digail.algos.model_selection import (
        by_codes_used,
        codes_used,
        smallest_used_within_one_se,
        smallest_within_one_se,
    )

    rng = np.random.default_rng(0)
    base = rng.normal(100.0, 10.0, 30)
    curve = [{"codes": 2, "episode_dl": base + 30.0, "code_demos": [40, 40]},
             {"codes": 3, "episode_dl": base + 5.0, "code_demos": [40, 40, 38]},
             {"codes": 4, "episode_dl": base + 4.9, "code_demos": [40, 40, 38, 4]},
             {"codes": 5, "episode_dl": base - 5.0, "code_demos": [40, 40, 38, 39, 1]},
             {"codes": 6, "episode_dl": base - 5.02 + np.resize([1.0, -1.0], 30),
              "code_demos": [40, 40, 38, 39, 30, 0]}]
    for c in curve:
        c["dl_per_step"] = float(np.mean(c["episode_dl"]))
        c["least_used"] = min(c["code_demos"]) / max(c["code_demos"])
    assert [codes_used(c, 0.5) for c in curve] == [2, 3, 3, 4, 5]
    assert by_codes_used(curve, 0.5) == [0, 2, 3, 4]  # of the two 3-code fits, the one asked for 4 is lower
    assert smallest_used_within_one_se(curve, 0.5) == (3, 4)  # 5 codes (the fit of 6) are within noise of 4
    assert smallest_within_one_se(curve, 0.5) == 1  # asked: only K = 2, 3 are weighed, and 3 is the lower

def test_every_benchmark_task_gets_as_many_codes_as_its_labels_take_values(minari_root: Path) -> None:
    """The benchmark scores one-to-one accuracy with K given: with fewer codes than label values the smallest
    labels cannot be matched (Four Rooms ran K = 4 against 5 labels, a ceiling of 0.876)."""
    from conftest import repo_module

    SHIPPED = repo_module("benchmarks/segmentation.py").SHIPPED  # noqa: N806

    for name, course in COURSES.items():
        ds = load_dataset(record_course(name, minari_root, seed=0, episodes=3))
        assert len(np.unique(np.concatenate(_labels(ds.trajs)))) == course.codes, name
    for name, spec in SHIPPED.items():
        ds = load_dataset(spec["demos"])
        assert len(np.unique(np.concatenate(_labels(ds.trajs)))) == spec["codes"], name


def test_ordered_pieces_of_a_long_demonstration_cut_on_a_grid() -> None:
    """A 30 000-step demonstration would need a 30 001 x 30 001 table for the exact cut: it is cut on a grid of
    at most 1000 candidate positions instead, each within one grid step of the change."""
    from digail.algos.segment_search import _ordered_pieces

    truth = np.repeat([0, 1, 2], [10_000, 15_000, 5_000])
    feat = np.array([[1.0], [-1.0], [3.0]])[truth]
    codes = _ordered_pieces(feat, 3)
    assert list(np.unique(codes)) == [0, 1, 2] and np.all(np.diff(codes) >= 0)
    assert np.mean(codes == truth) > 0.998


def test_capped_costs_bound_what_one_unpredictable_step_costs() -> None:
    """With `outlier_share` eps, a continuous dimension's step costs at most -log(eps / range) nats however far it
    is from the policy's prediction; without it, a step 5 units off at the variance floor costs about 125 000."""
    from digail.algos.segment_init import OUTLIER_SHARE
    from digail.algos.segment_models import _LinearPolicies

    assert VAEConfig().init_outlier_share == OUTLIER_SHARE  # the flag's default is the library's
    rng = np.random.default_rng(0)
    x = np.c_[rng.normal(size=(200, 2)), np.ones(200)]
    a = x[:, :1] + 1e-3 * rng.normal(size=(200, 1))
    span = float(a.max() - a.min())
    for share, capped in ((1e-3, True), (0.0, False)):
        policies = _LinearPolicies(1, 3, 1, False, 1e-3, outlier_share=share)
        policies.fit(x, a, np.zeros(200, np.int64))
        cost = -float(policies.loglik(x[:1], a[:1] + 5.0)[0, 0])
        assert (cost <= -np.log(1e-3 / span)) == capped
        assert capped or cost > 1e4


@pytest.mark.slow
def test_fetch_phases_and_pick_place_both_found_with_capped_costs() -> None:
    """The shipped Fetch demonstrations (25 000 steps) under the Gaussian action model the fetch preset pins: with
    the default capped costs the start finds the four phases (measured 0.935) and keeps pick / place (0.960); with
    the plain Gaussian the closing steps of each grasp took a code of their own (0.854; docs/experiments.md)."""
    ds = load_dataset("digail/fetchpickandplace/expert-v0")
    phases = [np.asarray(t.subtasks)[:len(t)] for t in ds.trajs]
    four = segmentation_metrics(hard_em_segmentation(ds.trajs, 4, False, seed=0, actions="gaussian"), phases)
    assert four["accuracy"] >= 0.9 and four["switches_per_episode"] <= 1.5 * 3
    pick_place = [np.minimum(p // 2, 1) for p in phases]
    two = segmentation_metrics(hard_em_segmentation(ds.trajs, 2, False, seed=0, actions="gaussian"), pick_place)
    assert two["accuracy"] >= 0.9
    plain = segmentation_metrics(hard_em_segmentation(ds.trajs, 4, False, seed=0, outlier_share=0.0,
                                                         actions="gaussian"), phases)
    assert plain["accuracy"] < 0.9


@pytest.fixture(scope="module")
def curved(tmp_path_factory: pytest.TempPathFactory) -> list:
    """12 episodes of the curved course, in a Minari root of their own (a recording keeps the episode count it was
    first made with, and other tests record 3)."""
    return load_dataset(record_course("curved", tmp_path_factory.mktemp("curved"), seed=0, episodes=12)).trajs


def test_curved_legs_need_policies_whose_action_turns_with_the_state(curved: list) -> None:
    """Three arcs joined smoothly: the direction never jumps, only the curvature changes. With the state weights
    shrunk hard (ridge 1.0, the Gaussian start's default) a code's policy is nearly one constant action and the arcs
    are cut into stretches of nearly constant direction; a small ridge (0.01, what docs/howto/choosing-k.md advises
    for the Gaussian start on curved paths) lets one code's action turn with the position (a rotation field is
    linear in it)."""
    trajs = curved[:8]
    labels = _labels(trajs)
    # the Gaussian start, whose ridge this is about (the default start's ridge for continuous actions is small)
    turning = segmentation_metrics(hard_em_segmentation(trajs, 3, False, seed=0, starts=2,
                                                        ridge=0.01, actions="gaussian"), labels)
    assert turning["accuracy"] >= 0.9 and turning["switches_per_episode"] <= 1.5 * 2
    stiff = segmentation_metrics(hard_em_segmentation(trajs, 3, False, seed=0, starts=2, ridge=1.0,
                                                      actions="gaussian"), labels)
    assert stiff["accuracy"] < 0.7 and stiff["switches_per_episode"] > 3


def test_codes_auto_with_smooth_policies_finds_the_curved_courses_three(curved: list) -> None:
    """The K curve (held-out description length per K, smallest K within one standard error of the lowest) on the
    curved course, whose answer is 3: policies on random Fourier features of the state explain each arc with one
    code, so the curve is flat past 3; linear policies keep buying a better fit with every further cut of an arc
    and choose more."""
    from digail.algos.model_selection import smallest_within_one_se
    from digail.algos.segment_init import heldout_codes_curve

    trajs = curved
    fit_idx, held_idx = heldout_split(len(trajs), 0.25, 0)
    fit_on, held = [trajs[i] for i in fit_idx], [trajs[i] for i in held_idx]
    chosen = {}
    for model in ("rff", "linear"):
        curve = heldout_codes_curve(fit_on, held, [2, 3, 4, 5, 6], False, seed=0, model=model)
        chosen[model] = curve[smallest_within_one_se(curve)]["codes"]
    assert chosen["rff"] == 3 and chosen["linear"] > 3, chosen


def test_random_fourier_features_are_seeded_and_scaled_by_the_states_spread() -> None:
    """The `rff` map keeps the state and the bias and adds its features between them; the same seed draws the
    same features, and states spread twice as wide get a bandwidth twice as large (the median heuristic), so the
    features of the scaled states are the same numbers. An unknown model name is an error."""
    from digail.algos.segment_init import _FeatureMap

    rng = np.random.default_rng(0)
    x = np.c_[rng.normal(size=(300, 3)), np.ones(300)]
    fmap = _FeatureMap("rff", n_features=16, seed=1).fit(x)
    z = fmap(x)
    assert z.shape == (300, 3 + 16 + 1)
    np.testing.assert_array_equal(z[:, :3], x[:, :3])
    np.testing.assert_array_equal(z[:, -1], 1.0)
    np.testing.assert_array_equal(_FeatureMap("rff", n_features=16, seed=1).fit(x)(x), z)
    wide = np.c_[2 * x[:, :3], x[:, 3:]]
    np.testing.assert_allclose(_FeatureMap("rff", n_features=16, seed=1).fit(wide)(wide)[:, 3:-1], z[:, 3:-1],
                               atol=1e-9)
    assert np.array_equal(_FeatureMap("linear").fit(x)(x), x)
    with pytest.raises(ValueError, match="unknown sub-task model"):
        _FeatureMap("mlp")


@pytest.mark.parametrize("count", ["used", "asked"])
def test_codes_auto_says_which_k_it_left_out(tmp_path: Path, capsys: pytest.CaptureFixture[str], count: str) -> None:
    """On Circle-World's demonstrations K = 3 leaves a code that far fewer demonstrations take than the others
    (measured: 0.39 as many): `--codes auto` records that the fit uses 2 codes alike and says so in its K line
    (`--vae.k-count used`, the default), or records it as not weighed (`asked`); K = 2 either way, and with
    `used` the fit asked for 3 is the one weighed for 2, its held-out description length being the lower."""
    from digail.cli import main

    assert main(["pretrain", "--demos", "digail/circleworld/expert-v0", "--codes", "auto", "--max-codes", "3",
                 "--preset", "smoke", "--vae.k-count", count, "--out", str(tmp_path / "vae")]) == 0
    config = json.loads((tmp_path / "vae" / "config.json").read_text())
    curve = config["k_selection"]
    assert config["vae"]["codes"] == 2
    assert [c["used"] for c in curve] == [2, 2] and [c["least_used"] >= 0.5 for c in curve] == [True, False]
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("K selection"))
    if count == "used":  # the fit asked for 3 describes the held-out actions better and stands for K = 2
        assert [c["weighed"] for c in curve] == [False, True] and [c["chosen"] for c in curve] == [False, True]
        assert re.search(r"K=2: -?[0-9.]+ \(not weighed\), K=3: -?[0-9.]+ \(uses 2 alike\) -> K = 2$", line), line
    else:
        assert [c["weighed"] for c in curve] == [True, False]
        assert re.search(r"K=2: -?[0-9.]+, K=3: -?[0-9.]+ \(codes used unevenly\) -> K = 2$", line), line


def test_a_course_on_a_grid_fits_the_env_it_was_recorded_in(minari_root: Path) -> None:
    """grid-six is recorded in the waypoint env made with `grid=True` (discrete actions), the same env id whose
    default has continuous ones: the check against the env makes it with the recorded arguments, so `digail
    pretrain` takes the data."""
    from digail.data.validation import check_dataset_env, recorded_env_kwargs

    ds = load_dataset(record_course("grid-six", minari_root, seed=0, episodes=3))
    assert recorded_env_kwargs(ds)["grid"] is True
    assert check_dataset_env(ds) is None


def test_robosuite_tasks_label_the_imported_fixtures_with_the_experts_phases(tmp_path: Path) -> None:
    """The robosuite tasks import the fixture as a user would and label every observation with the scripted expert's
    phase from the oracle file: 7 phases, in the expert's order, a label per observation."""
    from conftest import repo_module

    bench = repo_module("benchmarks/segmentation.py")
    demos, codes, shipped, description = bench.task_data("robosuite-pickplacecan", tmp_path)
    ds = load_dataset(demos)
    assert codes == 7 and shipped and "10 episodes, 1628 steps" in description
    for traj in ds.trajs:
        labels = np.asarray(traj.subtasks)
        assert len(labels) == len(traj.obs) and labels[0] == 0 and labels[-1] == 6
        assert np.all(np.diff(labels) >= 0)  # the expert goes through its phases once, in order
