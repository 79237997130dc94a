"""Reports: `digail run` writes figures, a video and a report that a real browser (headless Chromium) renders with
every image decoded; the page is self-contained and readable; `digail report --compare` builds the seeds page."""

from __future__ import annotations

import json
import re
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from digail import preset
from digail.cli import main
from digail.commands.report import smoothing_pair
from digail.viz.html_page import fmt
from digail.viz.report import BEFORE_POLISH, UNSMOOTHED, write_report

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync"]
"""How the test starts Chromium: headless, no sandbox (CI runs as root), nothing fetched (the machine is offline)."""


def _find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser"):
        exe = shutil.which(name)
        if exe:
            return exe
    return "/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None


@pytest.fixture(scope="session")
def chromium() -> str:
    """The system's Chromium (Debian's package `chromium`, which `.ci/run` installs); the browser checks skip,
    saying so, where none is installed."""
    exe = _find_chromium()
    if exe is None:
        pytest.skip("no Chromium is installed (Debian: `apt-get install chromium`, as `.ci/run` does); the browser "
                    "check of the report did not run")
    return exe


def browser_check(page_path: Path, chromium: str, screenshot: Path, width: int = 1200) -> list[dict]:
    """Open `page_path` in headless Chromium through Playwright, save a screenshot and return every <img>'s
    `complete` and `naturalWidth`."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.fail("the Python package playwright is missing; install the dev extra (`pip install -e '.[dev]'`).")
    with sync_playwright() as p, tempfile.TemporaryDirectory() as profile:
        ctx = p.chromium.launch_persistent_context(profile, executable_path=chromium, headless=True,
                                                   args=CHROMIUM_FLAGS, viewport={"width": width, "height": 900})
        try:
            page = ctx.new_page()
            page.goto(page_path.resolve().as_uri(), wait_until="load")
            images = page.evaluate("Array.from(document.images).map(i => ({alt: i.alt, complete: i.complete, "
                                   "width: i.naturalWidth}))")
            overflow = page.evaluate("document.documentElement.scrollWidth > window.innerWidth + 1")
            page.screenshot(path=str(screenshot), full_page=True)
        finally:
            ctx.close()
    assert not overflow, f"{page_path.name} scrolls sideways at {width} px"
    return images


def _check_page_text(text: str) -> None:
    assert "<script" not in text.lower()
    assert not re.search(r"""(src|href)\s*=\s*['"]?(https?:)?//""", text), "the page refers to an external asset"
    body = re.sub(r"data:image/[a-z]+;base64,[A-Za-z0-9+/=]+", "", text)
    for raw in (">None<", ">nan<", ">null<", "{'", '{"'):
        assert raw not in body, f"raw value {raw!r} in the page"
    for number in re.findall(r"\d+\.\d+", body):
        assert len(number.replace(".", "").lstrip("0")) <= 4, f"unrounded number {number} in the page"


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory):
    """`digail run` on Circle-World with SMOKE settings plus a smoothing term (SMOKE has none), so that the run
    also pre-trains the VAE without it for the side-by-side figure."""
    out = tmp_path_factory.mktemp("report") / "cw"
    smoke = preset.PRESETS["smoke"]
    weight = 0.1
    with pytest.MonkeyPatch.context() as mp:
        mp.setitem(preset.PRESETS, "smoke", replace(smoke, vae=replace(smoke.vae, smoothing_weight=weight)))
        assert main(["run", "digail/CircleWorld-v0", "--preset", "smoke", "--episodes", "4", "--out", str(out)]) == 0
    return out


def test_run_writes_figures_video_and_a_report_chromium_renders(smoke_run, chromium, tmp_path):
    run = smoke_run
    for name in ("learning_curves", "codes_time", "pca_codes", "generated", "compose", "segmentation_pair"):
        assert (run / "figures" / f"{name}.png").stat().st_size > 1000, name
    # the segmentation pair compares the run's VAE (before its polish) with one trained without the smoothing term
    with_term = json.loads((run / "vae" / "config.json").read_text())["vae"]
    without = json.loads((run / UNSMOOTHED / "config.json").read_text())["vae"]
    assert with_term["smoothing_weight"] > 0 and without["smoothing_weight"] == 0
    assert {k: v for k, v in without.items() if k not in ("smoothing_weight", "polish_steps")} == \
        {k: v for k, v in with_term.items() if k not in ("smoothing_weight", "polish_steps")}
    with np.load(run / "codes.npz") as z:
        demos = len(z.files)
    for folder in (run / BEFORE_POLISH, run / UNSMOOTHED):
        with np.load(folder / "codes.npz") as z:
            assert len(z.files) == demos == 100  # every shipped demonstration, segmented
    pair = smoothing_pair(run)
    assert pair is not None and "smoothing" in pair[3]
    assert "0.1" in pair[2][0] and "= 0" in pair[2][1] and "accuracy" in pair[2][0]
    assert "pretrain_unsmoothed_s" in json.loads((run / "timings.json").read_text())
    for ext in ("mp4", "gif"):
        assert (run / "videos" / f"closed_loop.{ext}").stat().st_size > 1000
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["command"].startswith("digail run digail/CircleWorld-v0")
    text = (run / "report.html").read_text()
    _check_page_text(text)
    assert text.index("class='headline'") < text.index("<img")
    assert "Circle-World" in text and "expert" in text and cfg["command"] in text
    assert "videos/closed_loop.mp4" in text and "data:image/gif;base64," in text
    assert "With and without the smoothing term" in text
    images = browser_check(run / "report.html", chromium, tmp_path / "laptop.png")
    assert len(images) >= 7
    assert all(i["complete"] and i["width"] > 0 for i in images), images
    shot = np.asarray(Image.open(tmp_path / "laptop.png").convert("L"), np.float64)
    assert shot.shape[1] == 1200 and shot.shape[0] > 2000 and shot.std() > 10, "the page rendered blank"
    phone = browser_check(run / "report.html", chromium, tmp_path / "phone.png", width=390)
    assert all(i["width"] > 0 for i in phone)


def test_four_rooms_run_report_renders(chromium, tmp_path):
    run = tmp_path / "fr"
    assert main(["run", "digail/FourRooms-v0", "--preset", "smoke", "--episodes", "4", "--out", str(run)]) == 0
    for name in ("four_rooms_codes", "four_rooms_paths", "learning_curves", "codes_time", "pca_codes"):
        assert (run / "figures" / f"{name}.png").stat().st_size > 1000, name
    assert (run / "videos" / "closed_loop.gif").exists() and (run / "videos" / "closed_loop.mp4").exists()
    text = (run / "report.html").read_text()
    _check_page_text(text)
    assert "Four Rooms" in text and "success rate" in text
    images = browser_check(run / "report.html", chromium, tmp_path / "fr.png", width=390)
    assert len(images) >= 6 and all(i["complete"] and i["width"] > 0 for i in images), images


def test_video_and_report_commands(smoke_run, chromium, tmp_path):
    run = smoke_run
    assert main(["video", str(run), "--episodes", "1", "--schedule", "1:20,0:20", "--seed", "3"]) == 0
    assert (run / "videos" / "composed.gif").exists() and (run / "videos" / "composed.mp4").exists()
    (run / "figures" / "segmentation_pair.png").unlink()
    assert main(["report", str(run), "--unsmoothed", str(run / "vae"), "--out", str(tmp_path / "r.html")]) == 0
    assert (run / "figures" / "segmentation_pair.png").exists()  # redrawn, beside the second VAE's segmentation
    assert "composed.mp4" in (tmp_path / "r.html").read_text()
    assert main(["report", str(run), "--no-figures", "--out", str(tmp_path / "r2.html")]) == 0
    second = tmp_path / "cw_s1"
    shutil.copytree(run, second)
    cfg = json.loads((second / "config.json").read_text())
    (second / "config.json").write_text(json.dumps({**cfg, "seed": 1}))
    page = tmp_path / "compare.html"
    assert main(["report", "--compare", str(run), str(second), "--out", str(page)]) == 0
    text = page.read_text()
    _check_page_text(text)
    assert "2 seeds" in text and "Directed-Info GAIL" in text
    images = browser_check(page, chromium, tmp_path / "compare.png")
    assert images and all(i["width"] > 0 for i in images)
    # a sweep folder keeps its runs one level further down (SWEEP/<env>/<run>)
    sweep = tmp_path / "sweep"
    for src, name in ((run, "digail_s0"), (second, "digail_s1")):
        shutil.copytree(src, sweep / "digail-CircleWorld-v0" / name, ignore=shutil.ignore_patterns("tb", "videos"))
    assert main(["report", "--compare", str(sweep)]) == 0
    assert "2 seeds" in (sweep / "compare.html").read_text()


def test_report_errors_are_one_sentence(tmp_path, capsys):
    assert main(["report", str(tmp_path / "missing")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["report", "--compare", str(tmp_path)]) == 2
    assert "no run folders" in capsys.readouterr().err


def test_fmt_rounds_and_names_units():
    assert fmt(0.12345, "pct") == "12.3%"
    assert fmt(1234.5678) == "1,235"
    assert fmt(-7.1e-08) == "0"
    assert fmt(float("nan")) == "not defined"
    assert fmt(185.0, "s") == "3 min 5 s"
    assert fmt(3, "steps") == "3 steps"


def test_minimal_run_folder_report(tmp_path):
    """A folder with only config.json and eval.json (a train run never evaluated further) still reports."""
    (tmp_path / "config.json").write_text(json.dumps({"method": "gail", "env_id": "Hopper-v5", "seed": 2,
                                                      "train": {"iterations": 10, "hidden": [64, 64]}}))
    (tmp_path / "eval.json").write_text(json.dumps({"episodes": 300, "mean_return": 3500.123456, "std_return": 20.5,
                                                    "normalized_return": 0.95, "expert": {"mean_return": 3684.2,
                                                                                          "std_return": 10.0}}))
    text = write_report(tmp_path).read_text()
    _check_page_text(text)
    assert "3,500" in text and "3.66e+03" not in text
    assert "0.95 ×" in text  # the normalised return, as `fmt(0.95, "x")` writes it
    assert "3,662" in text  # the paper's number for Hopper
    assert "about as well as the expert" in text
    # costs: a return 15 times the expert's negative one is far worse, not better
    (tmp_path / "eval.json").write_text(json.dumps({"episodes": 2, "mean_return": -994.0, "std_return": 94.8,
                                                    "normalized_return": 15.1, "expert": {"mean_return": -65.7}}))
    (tmp_path / "config.json").write_text(json.dumps({"method": "digail", "env_id": "Pendulum-v1", "seed": 0}))
    text = write_report(tmp_path).read_text()
    assert "has not learned the task" in text and "-994" in text


def test_report_names_a_closed_loop_order(tmp_path):
    """compose.json from `digail compose --order` is reported as the order it ran, with its completion rate."""
    (tmp_path / "config.json").write_text(json.dumps({"method": "digail", "env_id": "digail/CircleWorld-v0"}))
    (tmp_path / "compose.json").write_text(json.dumps({"episodes": 4, "order": [1, 0], "hold": 1,
                                                       "order_reversed_rate": 0.75, "order_completed_rate": 1.0,
                                                       "switch_steps": [[61]] * 4}))
    text = write_report(tmp_path).read_text()
    _check_page_text(text)
    assert "Composition (order <code>1,0</code>)" in text and "composed (order 1,0): reversed order drawn" in text
    assert "episodes whose code order ran to its last code" in text
