"""Scalar logging to CSV (always) and TensorBoard (when available), with namespaced names."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any


class ScalarLogger:
    """Appends one row per `log` call to `metrics.csv` and mirrors every scalar to TensorBoard.

    Names are namespaced (`losses/*`, `disc/*`, `rollout/*`, `perf/*`, ...); the README explains each.
    """

    def __init__(self, run_dir: Path, tensorboard: bool = True) -> None:
        self.path = Path(run_dir) / "metrics.csv"
        self._fields: list[str] | None = None
        if self.path.exists():
            with open(self.path) as f:
                header = f.readline().strip()
            self._fields = header.split(",") if header else None
        self._tb: Any = None
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter

                self._tb = SummaryWriter(str(Path(run_dir) / "tb"))
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

    def close(self) -> None:
        if self._tb is not None:
            self._tb.close()
