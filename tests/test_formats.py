"""Robot-learning datasets as their own libraries write them: imitation 1.0.1's datasets folder and flattened
transitions, robomimic 0.3.0 files, LeRobot 0.6.1 datasets (tests/data/formats, written by
scripts/make_format_fixtures_*.py in those libraries' own environments), read step for step against the episodes
they were made from; the segmentation written back as MimicGen signals, a LeRobot column and a segments table,
the input untouched; `digail import` and `digail segment --export` on the command line."""

from __future__ import annotations

import csv
import hashlib
import json
from pathlib import Path

import h5py
import numpy as np
import pyarrow.parquet as pq
import pytest
from conftest import repo_module

from digail.cli import main
from digail.data.annotations import export_segmentation, segments
from digail.data.importers import is_import_source, read_demonstrations
from digail.data.subtask_plan import term_signals
from digail.errors import UserError

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "tests" / "data" / "formats"
episodes = repo_module("scripts/format_fixture_episodes.py").episodes

IMITATION_DIR = FIXTURES / "imitation_dataset"
TRANSITIONS = FIXTURES / "imitation_transitions.npz"
ROBOMIMIC_D4RL = FIXTURES / "robomimic_d4rl.hdf5"
ROBOSUITE = FIXTURES / "robomimic_robosuite.hdf5"
LEROBOT = FIXTURES / "lerobot"


@pytest.fixture(scope="module")
def eps() -> list[dict[str, np.ndarray]]:
    return episodes()


def digest(path: Path) -> str:
    """A hash of a file, or of every file below a folder (names and contents)."""
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for file in files:
        h.update(str(file.relative_to(path) if path.is_dir() else file.name).encode())
        h.update(file.read_bytes())
    return h.hexdigest()


def one_sentence(exc: pytest.ExceptionInfo[UserError], *phrases: str) -> None:
    msg = str(exc.value)
    assert "\n" not in msg and msg.rstrip().endswith("."), msg
    for phrase in phrases:
        assert phrase in msg, msg


# ------------------------------------------------------------------------------------------------ reading
def test_versions_are_recorded():
    for lib, version in (("imitation", "1.0.1"), ("robomimic", "0.3.0"), ("lerobot", "0.6.1")):
        record = json.loads((FIXTURES / f"{lib}.versions.json").read_text())
        assert record[lib] == version and record["written_by"].startswith("scripts/make_format_fixtures_")


def test_imitation_dataset_folder(eps):
    assert is_import_source(IMITATION_DIR)
    im = read_demonstrations(IMITATION_DIR)
    assert im.fmt == "imitation-dataset" and "imitation trajectories folder" in im.found
    assert [len(t) for t in im.trajs] == [len(e["actions"]) for e in eps]
    for t, e in zip(im.trajs, eps, strict=True):
        np.testing.assert_allclose(t.obs, np.concatenate([e["eef"], e["object"][:, :3]], axis=1), rtol=1e-6)
        np.testing.assert_allclose(t.acts, e["actions"], rtol=1e-6)
        np.testing.assert_allclose(t.rews, e["rewards"], rtol=1e-6)
    # episode 1 is flagged terminal but its last info records a time limit: kept as truncated
    assert [t.terminated for t in im.trajs] == [True, False, False]
    assert any("TimeLimit.truncated" in n for n in im.notes)


def test_imitation_transitions_match_the_folder():
    folder, flat = read_demonstrations(IMITATION_DIR), read_demonstrations(TRANSITIONS)
    assert flat.fmt == "imitation-transitions"
    for a, b in zip(folder.trajs, flat.trajs, strict=True):
        np.testing.assert_array_equal(a.obs, b.obs)
        np.testing.assert_array_equal(a.acts, b.acts)
    # the unflagged end of episode 2 is found where next_obs stops being the next row's obs; the file cannot
    # tell episode 1's time limit from a terminal state (its infos are pickled and never read)
    assert [t.terminated for t in flat.trajs] == [True, True, False]
    assert any("without a 'dones' flag" in n for n in flat.notes)


def test_robomimic_written_by_its_d4rl_conversion(eps):
    im = read_demonstrations(ROBOMIMIC_D4RL)
    assert im.fmt == "robomimic" and "observation keys flat" in im.found
    assert im.metadata["env_args"]["env_name"] == "fixture-point-v0"
    # the conversion repeats each episode's last state as its last next_obs: that last action is dropped
    assert [len(t) for t in im.trajs] == [len(e["actions"]) - 1 for e in eps]
    assert any("D4RL conversion" in n for n in im.notes)
    for t, e in zip(im.trajs, eps, strict=True):
        np.testing.assert_allclose(t.obs, np.concatenate([e["eef"], e["object"][:, :3]], axis=1)[:len(t) + 1],
                                   rtol=1e-6)


def test_robomimic_keys_images_and_signals(eps):
    im = read_demonstrations(ROBOSUITE)
    assert im.episode_keys == ["demo_0", "demo_1", "demo_2"] and im.metadata["obs_keys"] == ["object",
                                                                                              "robot0_eef_pos"]
    assert "of Lift" in im.found and "filter keys train, valid" in im.found
    assert any("agentview_image" in n for n in im.notes)
    for t, e in zip(im.trajs, eps, strict=True):
        assert len(t) == len(e["actions"])  # next_obs holds the state after the last action
        np.testing.assert_allclose(t.obs, np.concatenate([e["object"], e["eef"]], axis=1), rtol=1e-6)
        np.testing.assert_array_equal(t.subtasks, e["phase"])  # MimicGen's grasp signal as oracle labels
    chosen = read_demonstrations(ROBOSUITE, obs_keys=["robot0_eef_pos", "object"])
    np.testing.assert_allclose(chosen.trajs[0].obs[:, :3], eps[0]["eef"], rtol=1e-6)
    with pytest.raises(UserError) as exc:
        read_demonstrations(ROBOSUITE, obs_keys=["agentview_image"])
    one_sentence(exc, "image", "robot0_eef_pos")
    with pytest.raises(UserError) as exc:
        read_demonstrations(ROBOSUITE, obs_keys=["joint_pos"])
    one_sentence(exc, "no observation key 'joint_pos'", "object, robot0_eef_pos")


def test_lerobot_dataset(eps):
    assert is_import_source(LEROBOT)
    im = read_demonstrations(LEROBOT)
    assert im.fmt == "lerobot" and "format v3.0" in im.found and im.episode_keys == ["0", "1", "2"]
    # a frame holds a state and its action, never the state after the last action: that action is dropped
    assert [len(t) for t in im.trajs] == [len(e["actions"]) - 1 for e in eps]
    for t, e in zip(im.trajs, eps, strict=True):
        np.testing.assert_allclose(t.obs, e["eef"][:len(t) + 1], rtol=1e-6)
        np.testing.assert_allclose(t.acts, e["actions"][:len(t)], rtol=1e-6)
        np.testing.assert_allclose(t.rews, e["rewards"][:len(t)], rtol=1e-6)
    both = read_demonstrations(LEROBOT, obs_keys=["observation.state", "observation.environment_state"])
    assert both.trajs[0].obs.shape[1] == 7
    with pytest.raises(UserError) as exc:
        read_demonstrations(LEROBOT, obs_keys=["observation.images.top"])
    one_sentence(exc, "no feature 'observation.images.top'")


def test_format_override_and_detection_errors(tmp_path):
    with pytest.raises(UserError) as exc:
        read_demonstrations(LEROBOT, fmt="robomimic")
    one_sentence(exc, "not a robomimic file")
    with pytest.raises(UserError) as exc:
        read_demonstrations(ROBOSUITE, fmt="lerobot")
    one_sentence(exc, "not a LeRobot dataset")
    assert read_demonstrations(IMITATION_DIR, fmt="imitation").fmt == "imitation-dataset"
    (tmp_path / "stuff").mkdir()
    with pytest.raises(UserError) as exc:
        read_demonstrations(tmp_path / "stuff")
    one_sentence(exc, "imitation trajectories folder", "LeRobot dataset")
    with pytest.raises(UserError) as exc:
        read_demonstrations(TRANSITIONS, obs_keys=["obs"])
    one_sentence(exc, "--obs-keys")


# ------------------------------------------------------------------------------------------------ writing
def test_term_signals_follow_mimicgen():
    codes = np.array([1, 1, 1, 0, 0, 2, 2, 2])
    sig = term_signals(codes, len(codes), 4)
    np.testing.assert_array_equal(sig[1], [0, 0, 0, 1, 1, 1, 1, 1])  # first segment ends before step 3
    np.testing.assert_array_equal(sig[0], [0, 0, 0, 0, 0, 1, 1, 1])
    assert not sig[2].any() and not sig[3].any()  # the last sub-task and an unused code stay 0
    assert segments(codes) == [(0, 3, 1), (3, 5, 0), (5, 8, 2)]


def test_robomimic_export_is_a_copy_with_signals(tmp_path):
    im = read_demonstrations(ROBOSUITE)
    codes = [np.where(np.arange(len(t)) < 5, 0, 1) for t in im.trajs]
    before = digest(ROBOSUITE)
    out = export_segmentation("robomimic", tmp_path / "annotated.hdf5", im.episode_keys, codes, ["reach", "carry"],
                              source=im.source)
    assert digest(ROBOSUITE) == before  # the input is never written
    with h5py.File(out, "r") as f:
        group = f["data/demo_1/datagen_info/subtask_term_signals"]
        assert sorted(group) == ["carry", "grasp", "reach"]  # the file's own annotation stays
        assert group["reach"].dtype == np.int64
        np.testing.assert_array_equal(group["reach"][()], np.arange(16) >= 5)
        assert not group["carry"][()].any()
        np.testing.assert_array_equal(f["data/demo_1/actions"][()], h5py.File(ROBOSUITE)["data/demo_1/actions"][()])
    # read back: digail's own signals are not taken for oracle labels
    again = read_demonstrations(out)
    np.testing.assert_array_equal(again.trajs[1].subtasks, im.trajs[1].subtasks)
    with pytest.raises(UserError) as exc:
        export_segmentation("robomimic", tmp_path / "twice.hdf5", im.episode_keys, codes, ["grasp", "x"],
                            source=im.source)
    one_sentence(exc, "already has datagen_info/subtask_term_signals/grasp")
    assert not (tmp_path / "twice.hdf5").exists() and not list(tmp_path.glob(".twice*"))
    with pytest.raises(UserError) as exc:
        export_segmentation("robomimic", ROBOSUITE, im.episode_keys, codes, ["a", "b"], source=im.source,
                            force=True)
    one_sentence(exc, "is the input;")
    assert digest(ROBOSUITE) == before


def test_lerobot_export_is_a_copy_with_a_column(tmp_path):
    im = read_demonstrations(LEROBOT)
    codes = [np.where(np.arange(len(t)) < 6, 1, 0) for t in im.trajs]
    before = digest(LEROBOT)
    out = export_segmentation("lerobot", tmp_path / "annotated", im.episode_keys, codes, ["carry", "reach"],
                              source=im.source)
    assert digest(LEROBOT) == before
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["features"]["subtask_index"] == {"dtype": "int64", "shape": [1], "names": None}
    names = pq.read_table(out / "meta" / "subtasks.parquet").to_pandas()
    assert names["subtask_index"].to_dict() == {"carry": 0, "reach": 1}  # names are the index, as tasks.parquet
    table = pq.read_table(out / "data" / "chunk-000" / "file-000.parquet")
    hf = json.loads(table.schema.metadata[b"huggingface"])
    assert hf["info"]["features"]["subtask_index"]["dtype"] == "int64"
    rows = table.to_pydict()
    for key, c in zip(im.episode_keys, codes, strict=True):
        frames = sorted((f, k) for e, f, k in zip(rows["episode_index"], rows["frame_index"], rows["subtask_index"],
                                                  strict=True) if e == int(key))
        assert [k for _, k in frames] == [*c.tolist(), int(c[-1])]  # the last frame takes the code before
    # read again, digail's own segmentation is not taken for oracle labels
    again = read_demonstrations(out)
    assert all(t.subtasks is None for t in again.trajs)
    assert any("a segmentation digail exported" in note for note in again.notes), again.notes


def test_table_exports(tmp_path):
    im = read_demonstrations(ROBOSUITE)
    codes = [np.where(np.arange(len(t)) < 5, 0, 1) for t in im.trajs]
    path = export_segmentation("csv", tmp_path / "seg.csv", im.episode_keys, codes, ["reach", "carry"],
                               reading="offline")
    rows = list(csv.DictReader(path.open()))
    assert rows[:2] == [{"episode": "demo_0", "start": "0", "end": "5", "code": "0", "name": "reach",
                         "reading": "offline"},
                        {"episode": "demo_0", "start": "5", "end": "14", "code": "1", "name": "carry",
                         "reading": "offline"}]
    data = json.loads(export_segmentation("json", tmp_path / "seg.json", im.episode_keys, codes,
                                          ["reach", "carry"], reading="causal").read_text())
    assert data["names"] == ["reach", "carry"] and len(data["segments"]) == 6 and data["reading"] == "causal"


# ------------------------------------------------------------------------------------------------ CLI
@pytest.fixture(scope="module")
def robomimic_vae(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("robomimic_cli")
    assert main(["import", str(ROBOSUITE), "--out", str(root / "demos")]) == 0
    assert main(["pretrain", "--demos", str(root / "demos"), "--codes", "2", "--preset", "smoke", "--out",
                 str(root / "vae")]) == 0
    return root


def test_cli_import_names_what_it_found(tmp_path, capsys):
    for source in (IMITATION_DIR, TRANSITIONS, ROBOMIMIC_D4RL, LEROBOT):
        assert main(["import", str(source), "--out", str(tmp_path / source.stem)]) == 0
        out = capsys.readouterr().out
        assert out.startswith("found ") and "imported 3 episodes" in out, out
    assert main(["import", str(LEROBOT), "--out", str(tmp_path / "again"), "--format", "robomimic"]) == 2
    assert "not a robomimic file" in capsys.readouterr().err


def test_cli_segment_exports(robomimic_vae, capsys):
    root = robomimic_vae
    before = digest(ROBOSUITE)
    # from the imported dataset: the source file is found through the dataset's record
    assert main(["segment", str(root / "vae"), "--demos", str(root / "demos"), "--export", "robomimic", "--names",
                 "a", "b", "--out", str(root / "annotated.hdf5")]) == 0
    out = capsys.readouterr().out
    assert "wrote the segmentation as robomimic annotations (a, b)" in out
    # one line says which sub-tasks, in which order, MimicGen's task spec should name
    order = "note: MimicGen sub-tasks in the demonstrated order: "
    assert len([ln for ln in out.splitlines() if ln.startswith(order)]) == 1
    with h5py.File(root / "annotated.hdf5", "r") as f:
        for key in ("demo_0", "demo_1", "demo_2"):
            group = f[f"data/{key}/datagen_info/subtask_term_signals"]
            assert {"a", "b", "grasp"} <= set(group) and len(group["a"]) == f[f"data/{key}/actions"].shape[0]
            assert group.attrs["digail_reading"] == "offline"
    # from the file itself, as a table
    assert main(["segment", str(root / "vae"), "--demos", str(ROBOSUITE), "--export", "csv", "--out",
                 str(root / "seg.csv")]) == 0
    table = (root / "seg.csv").read_text()
    # the default reading is the offline one, named in every row
    assert table.startswith("episode,start,end,code,name,reading\ndemo_0,0,") and ",offline\n" in table
    assert digest(ROBOSUITE) == before
    # refused before any work: an existing --out, a LeRobot export of a robomimic source, names of the wrong count
    for argv, phrase in (
        (["--export", "csv", "--out", str(root / "seg.csv")], "already exists"),
        (["--export", "lerobot", "--out", str(root / "lr")], "--export lerobot annotates a copy of the lerobot"),
        (["--export", "csv", "--names", "x", "--out", str(root / "x.csv")], "one name per code"),
        (["--out", str(root / "y.csv")], "go with --export"),
    ):
        assert main(["segment", str(root / "vae"), "--demos", str(ROBOSUITE), *argv]) == 2
        assert phrase in capsys.readouterr().err
    assert not (root / "lr").exists() and not (root / "x.csv").exists()
    assert main(["segment", str(root / "vae"), "--demos", str(root / "demos"), "--obs-keys", "object"]) == 2
    assert "--obs-keys applies when --demos is a robomimic file" in capsys.readouterr().err


def test_pretrain_on_a_foreign_folder_points_to_import(tmp_path, capsys):
    before = digest(LEROBOT)
    assert main(["pretrain", "--demos", str(LEROBOT), "--preset", "smoke", "--out", str(tmp_path / "vae")]) == 2
    err = capsys.readouterr().err
    assert f"digail import {LEROBOT} --out NEW_FOLDER" in err and "digail demos" not in err, err
    assert digest(LEROBOT) == before and not (tmp_path / "vae").exists()


def test_exports_match_what_the_libraries_loaded(tmp_path, eps):
    """scripts/check_format_exports.py exported the fixtures' phases and recorded what robomimic 0.3.0's
    SequenceDataset and LeRobot 0.6.1's LeRobotDataset loaded; digail's export of the same codes writes exactly
    that today."""
    names = ["reach", "carry"]
    rm = json.loads((FIXTURES / "robomimic.check.json").read_text())
    im = read_demonstrations(ROBOSUITE)
    codes = [e["phase"][:len(t)] for e, t in zip(eps, im.trajs, strict=True)]
    out = export_segmentation("robomimic", tmp_path / "rm.hdf5", im.episode_keys, codes, names, source=im.source)
    with h5py.File(out, "r") as f:
        for key, loaded in rm["signals"].items():
            for name in names:
                assert f[f"data/{key}/datagen_info/subtask_term_signals/{name}"][()].tolist() == loaded[name]
    lr = json.loads((FIXTURES / "lerobot.check.json").read_text())
    assert lr["lerobot"] == "0.6.1" and "subtask_index" in lr["features"] and lr["subtasks"] == {"reach": 0,
                                                                                               "carry": 1}
    im = read_demonstrations(LEROBOT)
    codes = [e["phase"][:len(t)] for e, t in zip(eps, im.trajs, strict=True)]
    out = export_segmentation("lerobot", tmp_path / "lr", im.episode_keys, codes, names, source=im.source)
    table = pq.read_table(out / "data" / "chunk-000" / "file-000.parquet").to_pydict()
    for episode, loaded in lr["subtask_index"].items():
        rows = [i for i, e in enumerate(table["episode_index"]) if e == int(episode)]
        assert [table["subtask_index"][i] for i in rows] == loaded
