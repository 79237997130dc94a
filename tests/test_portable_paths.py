"""Published commands, configs and run folders name paths relative to the repository, never the absolute path of
the machine they were made on (a reader re-runs them as written on any checkout)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import torch

from digail.sweep.publish import make_portable, portable_text

ROOT = Path(__file__).resolve().parents[1]


def _scanner():
    spec = importlib.util.spec_from_file_location("portable_paths", ROOT / "scripts" / "portable_paths.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_no_tracked_file_or_checkpoint_names_a_machine_path() -> None:
    scanner = _scanner()
    files = scanner.tracked_files()
    assert sum(p.suffix == ".pt" for p in files) >= 40  # the committed run folders' checkpoints are scanned too
    assert scanner.offenders(files) == []


def test_the_scanner_finds_machine_paths_and_spares_urls() -> None:
    pattern = _scanner().MACHINE_PATH
    for text in ("--out /tmp/x", '"vae": "/work/main/runs/a"', "cd /home/me/digail", "/root/.cache/x"):
        assert pattern.search(text), text
    for text in ("https://example.org/work/x", "runs/tmp/x", "$RUNS/work/x", "see docs/howto/cluster.md"):
        assert not pattern.search(text), text


def test_publishing_writes_paths_relative_to_the_root(tmp_path: Path) -> None:
    root = tmp_path / "repo"
    run = root / "runs" / "a"
    run.mkdir(parents=True)
    config = {"vae_run": str(root / "runs" / "vae_s0"), "demos": "digail/hopper/expert-v0", "out": str(run)}
    (run / "config.json").write_text(json.dumps(config))
    weights = torch.arange(6, dtype=torch.float32).reshape(2, 3)
    torch.save({"config_json": json.dumps(config), "state_dict": {"w": weights}}, run / "model.pt")

    assert portable_text(f"--vae {root}/runs/vae_s0 --out /elsewhere/x", root) == "--vae runs/vae_s0 --out /elsewhere/x"
    make_portable(run, root)
    saved = json.loads((run / "config.json").read_text())
    assert saved == {"vae_run": "runs/vae_s0", "demos": "digail/hopper/expert-v0", "out": "runs/a"}
    payload = torch.load(run / "model.pt", weights_only=True)
    assert json.loads(payload["config_json"]) == saved
    assert torch.equal(payload["state_dict"]["w"], weights)
