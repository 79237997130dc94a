"""Progress bars: redrawn in place on a terminal, a few whole lines in a log (off a terminal)."""

from __future__ import annotations

import io

import pytest

import digail.utils
from digail.cli import main
from digail.utils import progress_bar

ENV = "digail/FourRooms-v0"


class _Stream(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


def _run_bar(monkeypatch: pytest.MonkeyPatch, tty: bool, steps: int, seconds_per_step: float) -> str:
    """`steps` updates (each with a postfix) of a bar on a fake stderr, `seconds_per_step` apart on tqdm's clock."""
    stream = _Stream(tty)
    monkeypatch.setattr("sys.stderr", stream)
    now = [0.0]
    bar = progress_bar(steps, desc="test", unit="step")
    bar._time = lambda: now[0]  # tqdm reads its clock through this attribute
    bar.start_t = bar.last_print_t = 0.0
    for i in range(steps):
        now[0] = (i + 1) * seconds_per_step
        bar.set_postfix(i=i, refresh=False)
        bar.update(1)
    bar.close()
    return stream.getvalue()


def test_off_a_terminal_a_line_a_minute(monkeypatch: pytest.MonkeyPatch) -> None:
    """Off a terminal: whole lines, no carriage returns, about one a minute plus the first and the last."""
    text = _run_bar(monkeypatch, tty=False, steps=1200, seconds_per_step=1.0)  # 20 minutes
    lines = text.splitlines()
    assert "\r" not in text and text.endswith("\n")
    assert 18 <= len(lines) <= 23, lines
    assert lines[-1].startswith("test: 100%") and "1200/1200" in lines[-1]
    quick = _run_bar(monkeypatch, tty=False, steps=1200, seconds_per_step=0.01)  # 12 seconds
    assert len(quick.splitlines()) == 2, quick  # the start and the end


def test_on_a_terminal_the_bar_redraws_in_place(monkeypatch: pytest.MonkeyPatch) -> None:
    text = _run_bar(monkeypatch, tty=True, steps=1200, seconds_per_step=1.0)
    assert text.count("\r") > 100 and text.count("\n") <= 1


def test_disabled_draws_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    stream = _Stream(False)
    monkeypatch.setattr("sys.stderr", stream)
    bar = progress_bar(10, enabled=False)
    for _ in range(10):
        bar.set_postfix(x=1, refresh=False)
        bar.update(1)
    bar.close()
    assert stream.getvalue() == ""


def test_commands_off_a_terminal_write_a_few_lines(tmp_path, capsys: pytest.CaptureFixture[str],
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """Recording 60 demonstrations and training 40 iterations, with stderr captured (not a terminal): two lines
    per bar (start and end) rather than one redraw per episode or iteration."""
    monkeypatch.setattr(digail.utils, "PROGRESS_LOG_INTERVAL_S", 3600.0, raising=False)  # no minute passes here
    demos = tmp_path / "demos"
    assert main(["demos", ENV, "--episodes", "60", "--out", str(demos)]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err and len([ln for ln in err.splitlines() if "ep/s" in ln or "ep]" in ln]) == 2, err
    assert main(["train", "--demos", str(demos), "--method", "gail", "--preset", "smoke", "--out",
                 str(tmp_path / "run"), "--train.iterations", "40"]) == 0
    err = capsys.readouterr().err
    bar = [ln for ln in err.splitlines() if ln.startswith("gail")]
    assert "\r" not in err and len(bar) == 2 and "40/40" in bar[-1], err
