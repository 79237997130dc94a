"""Failure-path probes of `digail segment --export`: where an export may go (never the input, the run or a
user's file, never through a link or onto a device), what the source must allow, and that every refusal comes
before the run folder is touched. The probes, with what each gets, are the reliability page's section of the same
name (docs/reference/errors.md).
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from probe_data import lerobot, make_base, robomimic, segment, targets
from probe_kit import (
    ROOT,
    Probe,
    ProbeTable,
    assert_published,
    check_probe,
    cli,
    copy_base,
)

from digail.errors import UserError

ROBOSUITE = ROOT / "tests" / "data" / "robosuite"


DEEP = "[" * 100_000 + "]" * 100_000
"""JSON nested deeper than the parser goes"""

PROBES = ProbeTable()
probe = PROBES.add


def probe_on_base(pid: str, what: str, expect: str | None, setup: Callable[[Path], object] | None = None
                  ) -> Callable[[Callable[[Path], object]], Callable[[Path], object]]:
    """A probe whose folder starts as a copy of the base folder (`probe_data.make_base`) with the targets an export
    is aimed at (`probe_data.targets`), then what its own `setup` makes."""
    def prepare(tmp: Path) -> None:
        targets(tmp)
        if setup is not None:
            setup(tmp)

    return PROBES.add(pid, what, expect, prepare, on_base=True)


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_base(tmp_path_factory.mktemp("base"))


# ------------------------------------------------------------------------------------------------ exports
for _pid, _argv, _what, _expect in [
    ("export-csv-over-source", ["--demos", "src.hdf5", "--export", "csv", "--out", "src.hdf5", "--force"],
     "a csv export over the robomimic source, with `--force`", "is the input"),
    ("export-json-over-lerobot-info", ["--demos", "lr", "--export", "json", "--out", "lr/meta/info.json", "--force"],
     "a json export over the LeRobot source's `meta/info.json`, with `--force`", "is inside the input"),
    ("export-csv-over-run-dataset", ["--demos", "src.hdf5", "--export", "csv", "--out",
                                     "demos/data/main_data.hdf5", "--force"],
     "a csv export over the run's dataset file, with `--force`", "is inside the run's dataset"),
    ("export-lerobot-over-run-dataset", ["--demos", "lr", "--export", "lerobot", "--out", "demos", "--force"],
     "a LeRobot export over the run's Minari dataset, with `--force`", "is the run's dataset"),
    ("export-lerobot-over-run", ["--demos", "lr", "--export", "lerobot", "--out", "vae", "--force"],
     "a LeRobot export over the run folder itself, with `--force`", "is the run folder"),
    ("export-lerobot-holding-source", ["--demos", "lr", "--export", "lerobot", "--out", ".", "--force"],
     "a LeRobot export over `.`, the folder holding the source and the run, with `--force`", "--out . holds"),
    ("export-robomimic-over-model", ["--demos", "src.hdf5", "--export", "robomimic", "--out", "vae/model.pt",
                                     "--force"], "a robomimic export over the run's `model.pt`, with `--force`",
     "is inside the run folder"),
    ("export-csv-over-config", ["--demos", "src.hdf5", "--export", "csv", "--out", "vae/config.json", "--force"],
     "a csv export over the run's `config.json`, with `--force`", "is inside the run folder"),
    ("export-csv-new-in-run", ["--demos", "src.hdf5", "--export", "csv", "--out", "vae/seg.csv"],
     "a new csv file inside the run folder", "is inside the run folder"),
    ("export-from-dataset-over-source", ["--export", "csv", "--out", "src.hdf5", "--force"],
     "a csv export (of the run's own dataset) over the file it was imported from, with `--force`", "is the input"),
    ("export-csv-over-users-file", ["--demos", "src.hdf5", "--export", "csv", "--out", "notes.txt", "--force"],
     "a csv export over a user's `notes.txt`, with `--force`", "is not a csv export digail wrote"),
    ("export-json-over-bashrc", ["--demos", "src.hdf5", "--export", "json", "--out", "home/.bashrc", "--force"],
     "a json export over a user's `.bashrc`, with `--force`", "is not a json export digail wrote"),
    ("export-robomimic-over-users-hdf5", ["--demos", "src.hdf5", "--export", "robomimic", "--out", "other.hdf5",
                                         "--force"],
     "a robomimic export over a robomimic file digail did not annotate, with `--force`",
     "is not a robomimic export digail wrote"),
    ("export-csv-over-link", ["--demos", "src.hdf5", "--export", "csv", "--out", "link", "--force"],
     "a csv export onto a symbolic link to a user's file, with `--force`", "is a symbolic link"),
    ("export-csv-over-dangling-link", ["--demos", "src.hdf5", "--export", "csv", "--out", "dangling"],
     "a csv export onto a link to nothing, without `--force`", "is a symbolic link"),
    ("export-csv-over-fifo", ["--demos", "src.hdf5", "--export", "csv", "--out", "fifo", "--force"],
     "a csv export onto a FIFO, with `--force`", "is a FIFO"),
    # a socket stands for the devices: a probe must never aim at a real device (as root, a regression would replace
    # /dev/null with a file)
    ("export-csv-over-socket", ["--demos", "src.hdf5", "--export", "csv", "--out", "sock", "--force"],
     "a csv export onto a Unix socket (as onto a device), with `--force`", "is a socket"),
    ("export-csv-to-folder", ["--demos", "src.hdf5", "--export", "csv", "--out", "sub"],
     "a csv export to an existing folder", "is a folder, but --export csv writes a file"),
    ("export-csv-to-folder-force", ["--demos", "src.hdf5", "--export", "csv", "--out", "sub", "--force"],
     "a csv export to an existing folder, with `--force`", "is a folder, but --export csv writes a file"),
    ("export-lerobot-over-file", ["--demos", "lr", "--export", "lerobot", "--out", "notes.txt", "--force"],
     "a LeRobot export over a user's file, with `--force`", "is a file, but --export lerobot writes a folder"),
    ("export-lerobot-over-users-folder", ["--demos", "lr", "--export", "lerobot", "--out", "sub", "--force"],
     "a LeRobot export over a folder of the user's, with `--force`", "is not a folder digail made"),
    ("export-names-dot", ["--demos", "src.hdf5", "--export", "robomimic", "--names", ".", "..", "--out", "x.hdf5"],
     "`--names . ..` for a robomimic export", "neither '.' nor '..'"),
    ("export-csv-new", ["--demos", "src.hdf5", "--export", "csv", "--out", "seg.csv"], "a csv export to a new file",
     None),
    ("export-lerobot-new", ["--demos", "lr", "--export", "lerobot", "--out", "annotated"],
     "a LeRobot export to a new folder", None),
]:
    probe_on_base(_pid, f"`digail segment`: {_what}", _expect)(segment(*_argv))


@probe_on_base("export-device-check",
               "the export check of `--out /dev/null --force` (the check alone, which writes nothing)",
       "is a character device")
def _device(tmp: Path) -> None:
    from digail.data.annotations import check_export_target

    check_export_target("csv", Path("/dev/null"), force=True)


for _pid, _fmt, _src, _out in [("export-csv-again", "csv", "src.hdf5", "seg.csv"),
                               ("export-json-again", "json", "src.hdf5", "seg.json"),
                               ("export-robomimic-again", "robomimic", "src.hdf5", "annotated.hdf5"),
                               ("export-lerobot-again", "lerobot", "lr", "annotated")]:
    def _again(tmp: Path, fmt: str = _fmt, src: str = _src, out: str = _out) -> None:
        cli(tmp, "segment", "vae", "--demos", src, "--export", fmt, "--out", out)
        cli(tmp, "segment", "vae", "--demos", src, "--export", fmt, "--out", out, "--force")

    probe_on_base(_pid, f"`digail segment`: a {_fmt} export over digail's own earlier one, with `--force`",
                  None)(_again)


def _deep_config(tmp: Path) -> None:
    (tmp / "deep").mkdir()
    (tmp / "deep" / "config.json").write_text(DEEP)


probe_on_base(
    "export-lerobot-over-deep-config", "`digail segment`: a LeRobot export over a folder whose config.json nests "
      "lists 100,000 deep, with `--force`", "is not a folder digail made", setup=_deep_config)(
    segment("--demos", "lr", "--export", "lerobot", "--out", "deep", "--force"))


def _deep_metadata(tmp: Path) -> None:
    shutil.copytree(tmp / "demos", tmp / "deepds")
    (tmp / "deepds" / "data" / "metadata.json").write_text(DEEP)


probe_on_base(
    "export-from-deep-minari-metadata", "`digail segment --demos D --export csv` where D's metadata.json nests "
      "lists 100,000 deep", "cannot read deepds/data/metadata.json", setup=_deep_metadata)(
    segment("--demos", "deepds", "--export", "csv", "--out", "seg.csv"))


def _fifo_in_lerobot(tmp: Path) -> None:
    (tmp / "lr" / "videos").mkdir()
    os.mkfifo(tmp / "lr" / "videos" / "cam.mp4")


probe_on_base("export-lerobot-source-fifo", "`digail segment`: a LeRobot export of a dataset holding a FIFO "
      "(`videos/cam.mp4`)", "is a FIFO", setup=_fifo_in_lerobot)(
    segment("--demos", "lr", "--export", "lerobot", "--out", "annotated"))
probe_on_base("export-lerobot-source-link-out", "`digail segment`: a LeRobot export of a dataset holding a link to a "
      "user's file outside it", "outside the dataset folder",
      setup=lambda tmp: (tmp / "lr" / "meta" / "notes.txt").symlink_to(tmp / "notes.txt"))(
    segment("--demos", "lr", "--export", "lerobot", "--out", "annotated"))


@probe_on_base("export-source-removed", "the robomimic source removed between the segmentation and its export",
       "is no longer there")
def _source_removed(tmp: Path) -> None:
    from digail.data.annotations import export_segmentation
    from digail.data.importers import read_demonstrations

    im = read_demonstrations(tmp / "src.hdf5")
    (tmp / "src.hdf5").rename(tmp / "moved.hdf5")
    try:
        export_segmentation("robomimic", tmp / "x.hdf5", im.episode_keys, [np.zeros(len(t), int) for t in im.trajs],
                            ["p", "q"], source=im.source)
    finally:
        (tmp / "moved.hdf5").rename(tmp / "src.hdf5")


_VAE_CACHE: list[Path] = []


def _stack_vae(tmp: Path) -> None:
    """A copy of the robosuite Stack file as rs.hdf5 and a small VAE trained on it (made once, copied per probe)."""
    if not _VAE_CACHE:
        import atexit
        import tempfile

        base = Path(tempfile.mkdtemp(prefix="digail-stack-vae-"))
        atexit.register(shutil.rmtree, base, True)
        shutil.copy(ROBOSUITE / "stack.hdf5", base / "rs.hdf5")
        cli(base, "import", "rs.hdf5", "--out", "ds")
        cli(base, "pretrain", "--demos", "ds", "--codes", "2", "--preset", "smoke", "--vae.steps", "20",
            "--vae.init-steps", "0", "--out", "vae")
        _VAE_CACHE.append(base)
    shutil.copy(_VAE_CACHE[0] / "rs.hdf5", tmp / "rs.hdf5")
    shutil.copytree(_VAE_CACHE[0] / "vae", tmp / "stackvae")


for _pid, _argv, _expect in [
    ("rs-export-ok", ["--export", "robomimic", "--names", "reach", "place", "--out", "annotated.hdf5"], None),
    ("rs-export-names-slash", ["--export", "robomimic", "--names", "a/b", "c", "--out", "annotated.hdf5"],
     "--names must be distinct"),
    ("rs-export-names-count", ["--export", "robomimic", "--names", "reach", "--out", "annotated.hdf5"],
     "one name per code"),
    ("rs-export-over-source", ["--export", "robomimic", "--out", "rs.hdf5", "--force"], "rs.hdf5"),
    ("rs-export-csv-into-vae", ["--export", "csv", "--out", "stackvae/model.pt", "--force"], "model.pt"),
]:
    def _rs_export(tmp: Path, argv: tuple[str, ...] = tuple(_argv)) -> None:
        _stack_vae(tmp)
        before = (tmp / "rs.hdf5").read_bytes()
        try:
            cli(tmp, "segment", "stackvae", "--demos", "rs.hdf5", *argv)
        finally:
            assert (tmp / "rs.hdf5").read_bytes() == before, "the source changed"

    probe(_pid, f"`digail segment VAE --demos rs.hdf5 {' '.join(_argv)}` with a VAE of the robosuite-made Stack file",
          _expect)(_rs_export)


# ------------------------------------------------------------------------------------------------ refusals before work
def _signalled(tmp: Path) -> None:
    """sig.hdf5: the robomimic source with MimicGen signals `reach` and `place` of its own in every demonstration."""
    def edit(f: h5py.File) -> None:
        for demo in f["data"].values():
            for name in ("reach", "place"):
                demo[f"datagen_info/subtask_term_signals/{name}"] = np.zeros(len(demo["actions"]), np.int64)

    robomimic(tmp / "sig.hdf5", edit=edit)


def _lerobot_with_column(tmp: Path) -> None:
    """lr2: a LeRobot dataset that has a `subtask_index` column of its own (not digail's)."""
    lerobot(tmp / "lr2")
    frames = tmp / "lr2" / "data" / "chunk-000" / "file-000.parquet"
    table = pq.read_table(frames)
    pq.write_table(table.append_column("subtask_index", pa.array(np.zeros(len(table), np.int64))), frames)
    info = json.loads((tmp / "lr2" / "meta" / "info.json").read_text())
    info["features"]["subtask_index"] = {"dtype": "int64", "shape": [1], "names": None}
    (tmp / "lr2" / "meta" / "info.json").write_text(json.dumps(info))


def _frame_gap(tmp: Path) -> None:
    """gap/: the LeRobot source with a frame missing from its first episode."""
    lerobot(tmp / "gap", frame_gap=True)


def _digail_export(tmp: Path) -> None:
    """annotated.hdf5: digail's own robomimic export of the source (its signals code_0, code_1)."""
    cli(tmp, "segment", "vae", "--demos", "src.hdf5", "--export", "robomimic", "--out", "annotated.hdf5")


for _pid, _argv, _what, _setup, _expect in [
    ("export-names-clash", ["--demos", "sig.hdf5", "--export", "robomimic", "--names", "reach", "place", "--out",
                            "x.hdf5"], "a robomimic export whose `--names` clash with the source's own signals",
     _signalled, "already has datagen_info/subtask_term_signals/"),
    ("export-lerobot-has-column", ["--demos", "lr2", "--export", "lerobot", "--out", "annotated2"],
     "a LeRobot export of a dataset that has a `subtask_index` column already", _lerobot_with_column,
     "already has a 'subtask_index' feature"),
    ("export-robomimic-reexport", ["--demos", "annotated.hdf5", "--export", "robomimic", "--out", "again.hdf5"],
     "a robomimic export of digail's own robomimic export", _digail_export, "already has"),
    ("export-lerobot-frame-gap", ["--demos", "gap", "--export", "lerobot", "--out", "annotated2"],
     "a LeRobot export of a dataset whose episode skips a frame", _frame_gap, "skips frame_index 5"),
]:
    probe_on_base(_pid, f"`digail segment`: {_what} (the run folder as it was)", _expect, setup=_setup)(
        segment(*_argv))


# ---------------------------------------------------------------------------------------- tests beyond the probes
def test_segmenting_a_digail_lerobot_export_scores_no_oracle(base: Path, tmp_path: Path) -> None:
    """digail's own `subtask_index` column is a segmentation, not ground truth: segmenting the export again reports
    no oracle scores (before, it scored the model against itself)."""
    copy_base(base, tmp_path)
    cli(tmp_path, "segment", "vae", "--demos", "lr", "--export", "lerobot", "--out", "annotated")
    cli(tmp_path, "segment", "vae", "--demos", "annotated")
    metrics = json.loads((tmp_path / "vae" / "segmentation.json").read_text())
    assert metrics["labels"] is False and "accuracy" not in metrics, metrics


def test_an_export_of_a_read_only_source_is_writable_and_leaves_nothing_behind(base: Path, tmp_path: Path) -> None:
    """A LeRobot source the user cannot write (folders 0555, files 0444) is copied with its modes; the copy is made
    the owner's to write, so the column is added (as an unprivileged user it failed with "permission denied") and
    the export, or its temporary folder, can be removed by the user who made it."""
    import stat

    copy_base(base, tmp_path)
    for path in sorted((tmp_path / "lr").rglob("*"), reverse=True):
        path.chmod(0o444 if path.is_file() else 0o555)
    (tmp_path / "lr").chmod(0o555)
    try:
        cli(tmp_path, "segment", "vae", "--demos", "lr", "--export", "lerobot", "--out", "annotated")
    finally:
        for path in [tmp_path / "lr", *(tmp_path / "lr").rglob("*")]:
            path.chmod(0o755 if path.is_dir() else 0o644)
    written = [tmp_path / "annotated", *(tmp_path / "annotated").rglob("*")]
    assert all(p.stat().st_mode & stat.S_IWUSR for p in written), [p for p in written if not p.stat().st_mode & 0o200]
    assert not list(tmp_path.glob(".annotated.*"))


def test_a_replaced_export_that_cannot_be_removed_is_reported_as_it_is(base: Path, tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """`--force` over an earlier export whose files cannot be removed (an immutable `meta/`, `chattr +i`): the new
    export is in place and so is the run's segmentation of it, and the sentence says so and where the old one's
    remains are, instead of an error that reads as if the export failed."""
    import digail.fsio

    copy_base(base, tmp_path)
    cli(tmp_path, "segment", "vae", "--demos", "lr", "--export", "lerobot", "--out", "annotated")
    (tmp_path / "vae" / "segmentation.json").write_text("{}\n")  # what the run held before the second export
    real = digail.fsio.remove_path

    def immutable(path: Path) -> None:
        if ".old-" in str(path):
            raise PermissionError(1, "Operation not permitted", str(Path(path) / "meta" / "info.json"))
        real(path)

    monkeypatch.setattr(digail.fsio, "remove_path", immutable)
    with pytest.raises(UserError) as refused:
        cli(tmp_path, "segment", "vae", "--demos", "lr", "--export", "lerobot", "--out", "annotated", "--force")
    sentence = str(refused.value)
    assert sentence.startswith("the new annotated and the run's segmentation are in place"), sentence
    assert "operation not permitted" in sentence, sentence
    assert (tmp_path / "annotated" / "meta" / "subtasks.parquet").is_file()
    assert json.loads((tmp_path / "vae" / "segmentation.json").read_text()).get("reading") == "offline"
    assert not list(tmp_path.glob(".annotated.tmp-*"))
    left = list(tmp_path.glob(".annotated.old-*"))
    assert len(left) == 1 and left[0].name in sentence


# ------------------------------------------------------------------------------------------------ the probes
@pytest.mark.parametrize("p", PROBES, ids=[p.id for p in PROBES])
def test_probe(p: Probe, tmp_path: Path, request: pytest.FixtureRequest) -> None:
    check_probe(p, tmp_path, request.getfixturevalue("base") if p.on_base else None)


def test_the_reliability_page_lists_every_probe() -> None:
    assert_published(PROBES, "Probes: exports")
