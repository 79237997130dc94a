"""Presets as data: each file states only real departures with a reason and a source that exists, docs/presets.md
is what the files say, and `--preset paper` finds the paper's settings of an env."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from digail import config, preset
from digail.config import TrainConfig, VAEConfig
from digail.envs.registry import ENV_SPECS, preset_for
from digail.errors import UserError
from digail.preset import PRESET_FILES, PRESETS, Preset, get_preset

ROOT = Path(__file__).resolve().parents[1]


def _get(obj: object, key: str) -> object:
    for part in key.split("."):
        obj = getattr(obj, part)
    return obj


def _anchors(markdown: str) -> set[str]:
    """GitHub's heading anchors of a Markdown page."""
    return {re.sub(r"[^\w\- ]", "", line.lstrip("#").strip().lower()).replace(" ", "-")
            for line in markdown.splitlines() if line.startswith("#")}


def test_every_departure_departs_and_says_why_and_where() -> None:
    for name, spec in PRESET_FILES.items():
        base = PRESETS[spec.extends] if spec.extends else Preset(VAEConfig(), TrainConfig())
        for d in spec.departures:
            assert _get(base, d.key) != _get(PRESETS[name], d.key), f"{name}: {d.key} repeats what it builds on"
            assert d.why.strip() and "\n" not in d.why, f"{name}: {d.key} needs a one-line reason"
            if d.see.startswith("docs/"):
                page, _, anchor = d.see.partition("#")
                # a preset is read by users: its reason points at the guide or the results, not the dated logs
                assert not page.startswith("docs/experiments"), f"{name}: {d.key} points into a dated log"
                assert (ROOT / page).is_file(), f"{name}: {d.key} links to a missing page {page}"
                assert not anchor or anchor in _anchors((ROOT / page).read_text()), f"{name}: no heading #{anchor}"
            elif name != "smoke":
                assert d.see.startswith("paper"), f"{name}: {d.key} says neither where it was measured nor its source"


def test_no_history_in_preset_names() -> None:
    assert not hasattr(config, "VAE_BEFORE_ISSUE_14") and not hasattr(config, "TABLE1_EM_VAE")
    assert all(re.fullmatch(r"[a-z0-9]+(-[a-z0-9]+)*", name) for name in PRESETS)


def test_presets_doc_is_up_to_date() -> None:
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "presets_doc.py"), "--check"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_paper_preset_per_env() -> None:
    hopper = preset_for("Hopper-v5", "paper")
    assert hopper == PRESETS["paper-hopper"]
    assert (hopper.train.iterations, hopper.train.ppo.batch_size, hopper.train.bonus_weight) == (5000, 4096, 0.01)
    assert (hopper.vae.epochs, hopper.vae.batch_size, hopper.vae.init, hopper.vae.tau_decay) == (2000, 32, "none", 3e-3)
    rooms = preset_for("digail/FourRooms-v0", "paper")
    assert (rooms.train.ppo.batch_size, rooms.train.bonus_weight, rooms.vae.epochs) == (256, 0.1, 500)
    for spec in ENV_SPECS.values():
        assert spec.preset in PRESETS
        if f"paper-{spec.preset}" in PRESETS:
            assert preset_for(spec.env_id, "paper") == PRESETS[f"paper-{spec.preset}"]
    with pytest.raises(UserError, match="Table 3"):
        preset_for("digail/FetchPickAndPlace-v4", "paper")  # the paper gives no settings for Fetch
    with pytest.raises(UserError, match="unknown preset"):
        get_preset("four-rooms-v1")


def test_bad_preset_file_is_one_sentence(tmp_path: Path) -> None:
    (tmp_path / "a.toml").write_text('[train]\niterations = 3\n')
    with pytest.raises(UserError, match="iterations must be a table"):
        preset._load_presets(tmp_path)
    (tmp_path / "a.toml").write_text('extends = "b"\n')
    with pytest.raises(UserError, match="does not exist"):
        preset._load_presets(tmp_path)
    (tmp_path / "a.toml").write_text('[train]\nepochz = { value = 1, why = "x", see = "" }\n')
    with pytest.raises(UserError, match="unknown setting 'train.epochz'"):
        preset._load_presets(tmp_path)
