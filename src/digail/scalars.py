"""Scalar logging to CSV (always) and TensorBoard (when available), with namespaced names."""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path
from typing import Any


class ScalarLogger:
    """Appends one row per `log` call to `metrics.csv` and mirrors every scalar to TensorBoard.

    Names are namespaced (`losses/*`, `disc/*`, `rollout/*`, `perf/*`, ...); the README explains each.
    """

    def __init__(self, run_dir: Path, tensorboard: bool = True, resume_step: int | None = None) -> None:
        """`resume_step`: the env step of the checkpoint a resumed run continues from; rows logged after it (by
        the run that was stopped) are cut from `metrics.csv` and hidden in TensorBoard, so no step repeats."""
        self.path = Path(run_dir) / "metrics.csv"
        self._fields: list[str] | None = None
        if resume_step is not None:
            self.cut_after(resume_step)
        if self.path.exists():
            with open(self.path) as f:
                header = f.readline().strip()
            self._fields = header.split(",") if header else None
        self._tb: Any = None
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter

                purge = None if resume_step is None else resume_step + 1
                self._tb = SummaryWriter(str(Path(run_dir) / "tb"), purge_step=purge)
            except Exception:  # tensorboard missing or broken: CSV still works
                self._tb = None

    def log(self, step: int, scalars: dict[str, float]) -> None:
        row = {"step": step, **scalars}
        new = self._fields is None
        if new:
            self._fields = list(row)
        assert self._fields is not None
        extra = [k for k in row if k not in self._fields]
        if extra:  # a scalar logged only now and then (eval/*): widen the header once, keeping every old row
            self._fields += extra
            with open(self.path, newline="") as f:
                rows = list(csv.DictReader(f))
            with open(self.path, "w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=self._fields)
                writer.writeheader()
                writer.writerows(rows)
        with open(self.path, "a", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=self._fields, extrasaction="ignore")
            if new:
                writer.writeheader()
            writer.writerow(row)
        if self._tb is not None:
            for k, v in scalars.items():
                self._tb.add_scalar(k, v, step)

    def cut_after(self, step: int) -> None:
        """Drop the rows of `metrics.csv` logged after env step `step` (atomically; header kept)."""
        if not self.path.exists():
            return
        with open(self.path, newline="") as f:
            reader = csv.DictReader(f)
            fields = list(reader.fieldnames or [])
            rows = [r for r in reader if _step(r) <= step]
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=fields)
        if fields:
            writer.writeheader()
        writer.writerows(rows)
        tmp = self.path.with_name(f".{self.path.name}.cut")
        tmp.write_text(buf.getvalue())
        os.replace(tmp, self.path)  # never a half-cut file, whenever the run stops

    def close(self) -> None:
        if self._tb is not None:
            self._tb.close()


def _step(row: dict[str, Any]) -> float:
    try:
        return float(row.get("step") or 0)
    except ValueError:
        return float("inf")  # a torn last line from a killed run goes too
