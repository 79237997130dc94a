"""The paper's reported numbers (`paper.toml`): Table 1's returns on continuous control and Table 2's on Fetch."""

from __future__ import annotations

import functools
import tomllib
from pathlib import Path
from typing import Any

PAPER_FILE = Path(__file__).resolve().parent / "paper.toml"


@functools.cache
def _data() -> dict[str, Any]:
    with open(PAPER_FILE, "rb") as f:
        return tomllib.load(f)


def table(name: str) -> dict[str, dict[str, tuple[float, float]]]:
    """`table1` or `table2`: env id -> method -> (mean, std) of the paper's returns."""
    return {env: {method: (float(v[0]), float(v[1])) for method, v in methods.items()}
            for env, methods in _data()[name]["returns"].items()}


def episodes(name: str) -> int:
    """How many episodes the paper's table `name` averages over."""
    return int(_data()[name]["episodes"])


def paper_return(env_id: str, method: str = "digail") -> tuple[float, float] | None:
    """The paper's mean and std return of `method` on `env_id` (Table 1, or Table 2 for Fetch), or None."""
    for name in ("table1", "table2"):
        found = table(name).get(env_id, {}).get(method)
        if found is not None:
            return found
    return None
