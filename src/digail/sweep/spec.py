"""What a sweep asks for: grids of envs x methods x seeds x override values, from flags or a small TOML file.

A spec file holds top-level defaults and any number of `[[grid]]` blocks; a file without blocks is one grid.
Every block inherits the top-level keys and may override them, so tables whose rows differ (Table 1's L2 rows on
two envs only, plain GAIL with its own learning rate) are a few blocks:

```toml
seeds = [0, 1, 2]
episodes = 300
[set]                                  # overrides for every grid; a list is a list of values to sweep
"train.eval_episodes" = 5

[[grid]]
envs = ["Hopper-v5"]
methods = ["vae", "gail", "digail", "gail-l2", "digail-l2"]
set = { "train.iterations" = 732 }
```

Override keys name a field of the stage that takes it: `vae.*` and `train.*` are the nested configs of
`digail pretrain` / `digail train` (`train.ppo.policy_lr`), `pretrain.X`, `evaluate.X` and `segment.X` a stage's own
flag (`pretrain.codes`). `train.bc_weight` also sets the weight of the `-l2` methods.
`demos.episodes` and `demos.subsample` choose the demonstrations of both the VAE and the training
(`--demos-episodes`, `--demos-subsample`).

Overrides set hyper-parameters only, by an allow-list (`check_key`): the nested configs' fields and the stage settings
of `STAGE_OWN_SETTINGS`. A stage's outputs, inputs and control flags (`out`, `force`, `resume`, `demos`, `vae`,
`device`) belong to the sweep, which keeps every trial inside its folder.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from digail.errors import UserError

Value = str | int | float | bool | None | tuple[Any, ...]
"""one value of an override, as it will be written on the command line"""

METHODS: dict[str, tuple[str | None, bool]] = {
    "vae": (None, False),
    "gail": ("gail", False),
    "digail": ("digail", False),
    "gail-l2": ("gail", True),
    "digail-l2": ("digail", True),
}
"""method name -> (`digail train --method`, or None for the VAE baseline; whether it adds the BC / L2 term)"""

STAGE_PREFIXES = ("vae", "train", "pretrain", "evaluate", "segment", "demos")
"""first part of an override key: the nested config or stage it goes to"""

DEFAULT_BC_WEIGHT = 1.0
"""weight of the BC / L2 term of the `-l2` methods (the Table 1 harness's); `--set train.bc_weight=W` overrides"""


@dataclass(frozen=True)
class Range:
    """A search range for an override, `LOW..HIGH` or `LOW..HIGH:log` (integers when both ends are)."""

    low: float
    """lower end"""
    high: float
    """upper end"""
    log: bool = False
    """sample on a log scale"""
    integer: bool = False
    """sample integers"""

    def __str__(self) -> str:
        return f"{self.low:g}..{self.high:g}{':log' if self.log else ''}"


@dataclass(frozen=True)
class Grid:
    """One block of trials: every combination of envs x methods x seeds x override values."""

    envs: tuple[str, ...]
    """environment ids, e.g. digail/CircleWorld-v0"""
    methods: tuple[str, ...] = ("digail",)
    """methods: vae, gail, digail, gail-l2, digail-l2"""
    seeds: tuple[int, ...] = (0,)
    """seeds; trials of one (env, seed) share the VAE"""
    preset: str | None = None
    """settings preset of every stage (default: the env's)"""
    demos: str | None = None
    """demonstrations (default: the env's shipped dataset); only with a single env"""
    episodes: int | None = None
    """evaluation episodes (default: the preset's, 300 in the paper)"""
    overrides: tuple[tuple[str, tuple[Value | Range, ...]], ...] = ()
    """(key, values) pairs; a key with several values multiplies the trials, a Range is searched"""
    bc_weight: float = DEFAULT_BC_WEIGHT
    """weight of the BC / L2 term of the grid's `-l2` methods (`--set train.bc_weight=W` overrides it)"""
    compose: str | None = None
    """after evaluation, `digail compose` the trained policy and its VAE under this schedule of oracle labels,
    'label:steps,...' (e.g. '1:60,0:60'), translated into each run's own code ids by its segmentation"""

    def __post_init__(self) -> None:
        if not self.envs:
            raise UserError("a sweep grid needs at least one env; pass --envs or `envs = [...]` in the spec.")
        if not self.seeds:
            raise UserError("a sweep grid needs at least one seed; pass --seeds.")
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown or not self.methods:
            raise UserError(f"unknown method {', '.join(unknown) or '(none)'}; choose from {', '.join(METHODS)}.")
        if self.demos is not None and len(self.envs) > 1:
            raise UserError("`demos` names one dataset, so a grid with it takes a single env; split the grid.")
        bad = [e for e in self.envs if not isinstance(e, str) or not e]
        if bad:
            raise UserError(f"env {bad[0]!r} is not an environment id; write envs as strings, e.g. "
                            "envs = [\"digail/CircleWorld-v0\"].")
        for seed in self.seeds:
            if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed < 2**32:
                raise UserError(f"seed {seed!r} is not a seed; write seeds as integers from 0 to 2**32 - 1, "
                                "e.g. seeds = [0, 1, 2].")
        if self.episodes is not None and (not isinstance(self.episodes, int) or isinstance(self.episodes, bool)
                                          or self.episodes < 1):
            raise UserError(f"episodes must be a whole number of at least 1, got {self.episodes!r}.")
        for key, values in self.overrides:
            check_key(key)
            for value in values:
                check_value(key, value)


@dataclass(frozen=True)
class SearchSpec:
    """A hyper-parameter search with Optuna through Ray Tune over the grids' Range overrides."""

    trials: int = 8
    """number of sampled settings"""
    metric: str = "eval/normalized_return"
    """what to optimise: eval/<key of eval.json> or seg/<key of segmentation.json>, median over the seeds"""
    mode: str = "max"
    """max or min"""
    algo: str = "optuna"
    """search algorithm (Optuna's TPE)"""


@dataclass(frozen=True)
class SweepSpec:
    """A whole sweep: its grids and how to run them."""

    grids: tuple[Grid, ...]
    """blocks of trials"""
    retries: int = 1
    """extra attempts of a failed trial before it is reported failed"""
    cpus_per_trial: float = 1.0
    """CPUs each trial declares to Ray (the CLI's torch runs one thread)"""
    gpus_per_trial: float = 0.0
    """GPUs each trial declares to Ray"""
    search: SearchSpec | None = None
    """a search instead of a grid"""
    name: str = ""
    """a name for the tables"""
    resources_per_trial: tuple[tuple[str, float], ...] = ()
    """custom Ray resources each trial declares, e.g. (("worker", 1.0),): trials run only on nodes that have them"""

    def __post_init__(self) -> None:
        if not isinstance(self.retries, int) or isinstance(self.retries, bool) or self.retries < 0:
            raise UserError(f"retries must be a whole number of at least 0, got {self.retries!r}.")
        if not self.cpus_per_trial > 0:
            raise UserError(f"cpus per trial must be more than 0, got {self.cpus_per_trial!r}.")
        if not self.gpus_per_trial >= 0:
            raise UserError(f"gpus per trial must be 0 or more, got {self.gpus_per_trial!r}.")
        for name, amount in self.resources_per_trial:
            if not amount > 0:
                raise UserError(f"resource {name!r} per trial must be more than 0, got {amount!r}.")

    def with_flags(self, **changes: Any) -> SweepSpec:
        """A copy with the non-None `changes` applied."""
        return replace(self, **{k: v for k, v in changes.items() if v is not None})


STAGE_OWN_SETTINGS: dict[str, tuple[str, ...]] = {
    "pretrain": ("codes", "max_codes"),
    "evaluate": ("episodes", "seed", "stochastic", "video"),
    "segment": ("label_map",),
    "demos": ("episodes", "subsample"),
}
"""a stage's own flags that an override may set: hyper-parameters only. Its outputs, inputs and control flags
(`out`, `force`, `resume`, `demos`, `vae`, `device`, `preset`, `seed` of a training) belong to the sweep, which
writes every trial inside its folder; an override that could name them could write or wipe any folder."""

NESTED_SETTINGS = ("vae", "train")
"""prefixes whose keys are fields of the stage's nested config (`VAEConfig`, `TrainConfig`): hyper-parameters by
construction, none of them a path"""

SWEEP_OWNED_FIELDS = ("train.method", "vae.codes")
"""nested fields the command line does not take: the sweep sets the method, and K is `pretrain.codes`"""

_KEY_RE = re.compile(r"[a-z][a-z0-9_]*(\.[a-z][a-z0-9_]*)+")


def allowed_settings() -> str:
    """The settings an override may change, as written in a refusal."""
    own = ", ".join(f"{stage}.{name}" for stage, names in STAGE_OWN_SETTINGS.items() for name in names)
    return f"vae.* and train.* (the fields of `digail pretrain --help` and `digail train --help`), {own}"


def check_key(key: str) -> None:
    """Raise a UserError unless `key` names a setting an override may change (an allow-list: see
    `STAGE_OWN_SETTINGS` and `NESTED_SETTINGS`), e.g. train.ppo.policy_lr."""
    head, _, rest = key.partition(".")
    if head not in STAGE_PREFIXES or not rest:
        raise UserError(f"override {key!r} names no stage option; start it with one of "
                        f"{', '.join(p + '.' for p in STAGE_PREFIXES)} (e.g. train.bonus_weight=0.1).")
    if _KEY_RE.fullmatch(key) is None or not _allowed(head, rest) or key in SWEEP_OWNED_FIELDS:
        raise UserError(f"override {key!r} is not a setting a sweep may change (a sweep owns every stage's "
                        f"outputs, inputs and control flags); allowed: {allowed_settings()}.")


def _allowed(head: str, rest: str) -> bool:
    if head not in NESTED_SETTINGS:
        return rest in STAGE_OWN_SETTINGS.get(head, ())
    import dataclasses

    from digail.config import TrainConfig, VAEConfig

    node: Any = VAEConfig if head == "vae" else TrainConfig
    for part in rest.split("."):
        if not (dataclasses.is_dataclass(node) and isinstance(node, type)):
            return False
        found = {f.name: f for f in dataclasses.fields(node)}.get(part)
        if found is None:
            return False
        node = found.default_factory() if found.default_factory is not dataclasses.MISSING else found.default
        node = type(node) if dataclasses.is_dataclass(node) else None
    return node is None  # a leaf value, not a whole nested config


def check_value(key: str, value: Value | Range) -> None:
    """Refuse a value that the command line would read as a flag (`--out`, in a tuple `64 --force`): every value
    is a value of its own setting, never another option."""
    items = value if isinstance(value, tuple) else (value,)
    for item in items:
        if isinstance(item, str) and item.startswith("-") and not _looks_numeric(item):
            raise UserError(f"override {key}={item!r}: a value may not start with '-' (it would be read as another "
                            "option); give a number or a word.")
        if isinstance(item, tuple | list | dict):
            raise UserError(f"override {key}: {item!r} nests a list in a list; give numbers or words.")


def parse_value(text: str) -> Value | Range:
    """A value from the command line: numbers, true / false / none, LOW..HIGH[:log] ranges, else the string."""
    text = text.strip()
    if ".." in text and not text.startswith("."):
        body, _, opt = text.partition(":")
        lo, _, hi = body.partition("..")
        try:
            low, high = _number(lo), _number(hi)
        except ValueError:
            if _looks_numeric(lo) or _looks_numeric(hi):  # half a range (0.1..), not a string value
                raise UserError(f"range {text!r} is malformed; write LOW..HIGH or LOW..HIGH:log with two numbers, "
                                "e.g. 0.01..0.1:log.") from None
        else:
            if opt not in ("", "log"):
                raise UserError(f"range {text!r}: write LOW..HIGH or LOW..HIGH:log.")
            if not high > low or (opt == "log" and low <= 0):
                raise UserError(f"range {text!r} is empty or (log scale) not positive; write LOW..HIGH, LOW < HIGH.")
            integer = isinstance(low, int) and isinstance(high, int)
            return Range(float(low), float(high), log=opt == "log", integer=integer)
    lowered = text.lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    if lowered == "none":
        return None
    try:
        return _number(text)
    except ValueError:
        return text


def _looks_numeric(text: str) -> bool:
    try:
        _number(text)
    except ValueError:
        return False
    return True


def _number(text: str) -> int | float:
    try:
        return int(text)
    except ValueError:
        value = float(text)
        if not math.isfinite(value):
            raise ValueError(text) from None
        return value


def parse_set(items: list[str] | tuple[str, ...]) -> tuple[tuple[str, tuple[Value | Range, ...]], ...]:
    """`KEY=V1,V2` items (a value with spaces, e.g. '0 26', is a tuple) into (key, values) pairs."""
    out: dict[str, tuple[Value | Range, ...]] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise UserError(f"--set {item!r}: write KEY=VALUE or KEY=V1,V2 (e.g. train.bonus_weight=0.01,0.1).")
        key = key.strip().replace("-", "_")
        check_key(key)
        out[key] = tuple(_tuple_or_value(v) for v in text.split(","))
    return tuple(out.items())


def _tuple_or_value(text: str) -> Value | Range:
    parts = text.split()
    if len(parts) > 1:
        return tuple(parse_value(p) for p in parts)
    return parse_value(text)


def _toml_values(key: str, value: Any) -> tuple[Value | Range, ...]:
    """A TOML override: a list is values to sweep (an inner list a tuple value), a string may be a range."""
    items = value if isinstance(value, list) else [value]
    out: list[Value | Range] = []
    for item in items:
        if isinstance(item, list):
            out.append(tuple(item))
        elif isinstance(item, str):
            out.append(parse_value(item))
        elif isinstance(item, dict):
            try:
                out.append(Range(float(item["low"]), float(item["high"]), bool(item.get("log", False)),
                                 isinstance(item["low"], int) and isinstance(item["high"], int)))
            except KeyError as exc:
                raise UserError(f"override {key!r}: a range table needs low and high.") from exc
        else:
            out.append(item)
    return tuple(out)


GRID_KEYS = {"envs", "methods", "seeds", "preset", "demos", "episodes", "set", "compose", "bc_weight"}
TOP_KEYS = GRID_KEYS | {"grid", "retries", "cpus_per_trial", "gpus_per_trial", "search", "name", "resources_per_trial"}


def load_spec(path: Path | str) -> SweepSpec:
    """Read a TOML sweep spec (see the module docstring)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError as exc:
        raise UserError(f"no sweep spec at {path}; pass an existing TOML file to --spec.") from exc
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"{path} is not valid TOML ({exc}); fix the file.") from exc
    return spec_from_dict(data, str(path))


def spec_from_dict(data: dict[str, Any], where: str = "spec") -> SweepSpec:
    """A SweepSpec from the parsed TOML of a spec file."""
    unknown = set(data) - TOP_KEYS
    if unknown:
        raise UserError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}; "
                        f"allowed: {', '.join(sorted(TOP_KEYS))}.")
    top = {k: v for k, v in data.items() if k in GRID_KEYS}
    blocks = data.get("grid") or [{}]
    grids = []
    for i, block in enumerate(blocks):
        bad = set(block) - GRID_KEYS
        if bad:
            raise UserError(f"{where}: grid {i}: unknown key(s) {', '.join(sorted(bad))}.")
        merged = {**top, **block}
        if not all(isinstance(d.get("set", {}), dict) for d in (top, block)):
            raise UserError(f"{where}: grid {i}: set must be a table of overrides, e.g. set = {{ \"train.x\" = 1 }}.")
        sets = {**top.get("set", {}), **block.get("set", {})}
        if "envs" not in merged:
            raise UserError(f"{where}: grid {i} has no envs; add `envs = [...]`.")
        grids.append(Grid(
            envs=_list(merged["envs"], "envs", where),
            methods=_list(merged.get("methods", ["digail"]), "methods", where),
            seeds=_list(merged.get("seeds", [0]), "seeds", where), preset=merged.get("preset"),
            demos=merged.get("demos"), episodes=merged.get("episodes"), compose=merged.get("compose") or None,
            bc_weight=_float(merged.get("bc_weight", DEFAULT_BC_WEIGHT), "bc_weight", where),
            overrides=tuple((k.replace("-", "_"), _toml_values(k, v)) for k, v in sets.items())))
    search = None
    if "search" in data:
        allowed = {f.name for f in fields(SearchSpec)}
        if not isinstance(data["search"], dict) or set(data["search"]) - allowed:
            extra = sorted(set(data["search"]) - allowed) if isinstance(data["search"], dict) else ["(not a table)"]
            raise UserError(f"{where}: [search] has unknown key(s) {', '.join(extra)}; allowed: "
                            f"{', '.join(sorted(allowed))}.")
        search = SearchSpec(**data["search"])
    resources = data.get("resources_per_trial", {})
    if not isinstance(resources, dict) or not all(_is_number(v) for v in resources.values()):
        raise UserError(f"{where}: resources_per_trial must be a table of numbers, e.g. {{ worker = 1 }}.")
    return SweepSpec(grids=tuple(grids), retries=_whole(data.get("retries", 1), "retries", where),
                     cpus_per_trial=_float(data.get("cpus_per_trial", 1.0), "cpus_per_trial", where),
                     gpus_per_trial=_float(data.get("gpus_per_trial", 0.0), "gpus_per_trial", where), search=search,
                     name=str(data.get("name", "")),
                     resources_per_trial=tuple((str(k), float(v)) for k, v in sorted(resources.items())))


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _whole(value: Any, key: str, where: str) -> Any:
    if isinstance(value, bool) or not isinstance(value, int):
        raise UserError(f"{where}: {key} must be a whole number, got {value!r}.")
    return value


def _float(value: Any, key: str, where: str) -> float:
    if not _is_number(value):
        raise UserError(f"{where}: {key} must be a number, got {value!r}.")
    return float(value)


def _list(value: Any, key: str, where: str) -> tuple[Any, ...]:
    if not isinstance(value, list | tuple):
        raise UserError(f"{where}: {key} must be a list, e.g. {key} = [...], got {value!r}.")
    return tuple(value)


def merge_overrides(grid: Grid, extra: tuple[tuple[str, tuple[Value | Range, ...]], ...]) -> Grid:
    """`grid` with the command line's overrides added (they win over the spec's)."""
    merged = dict(grid.overrides)
    merged.update(dict(extra))
    return replace(grid, overrides=tuple(merged.items()))



def build_spec(*, envs: tuple[str, ...] | None = None, methods: tuple[str, ...] | None = None,
               seeds: tuple[int, ...] | None = None, preset: str | None = None, episodes: int | None = None,
               sets: tuple[str, ...] = (), spec_file: Path | None = None, retries: int | None = None,
               cpus_per_trial: float | None = None, gpus_per_trial: float | None = None, search: str | None = None,
               trials: int | None = None, metric: str | None = None, mode: str | None = None) -> SweepSpec:
    """The spec of a `digail sweep` call: the spec file's (if any), its grids narrowed or replaced by the flags.

    With a spec file, --envs / --methods / --seeds keep only those of its trials, --preset / --episodes replace the
    file's, and --set adds (or replaces) overrides in every grid. Without one the flags are a single grid.
    None means a flag was not given; an empty tuple that it was given without values, which is refused."""
    for flag, given in (("--envs", envs), ("--methods", methods), ("--seeds", seeds)):
        if given is not None and not given:
            raise UserError(f"{flag} was given no value; name at least one after it (or leave the flag out).")
    if episodes is not None and episodes < 1:
        raise UserError(f"--episodes must be at least 1, got {episodes}.")
    if trials is not None and trials < 1:
        raise UserError(f"--trials must be at least 1, got {trials}.")
    envs, methods, seeds = envs or (), methods or (), seeds or ()
    extra = parse_set(sets)
    if spec_file is not None:
        spec = load_spec(spec_file)
        grids = []
        for g in spec.grids:
            kept_envs = tuple(e for e in g.envs if not envs or e in envs)
            kept_methods = tuple(m for m in g.methods if not methods or m in methods)
            kept_seeds = tuple(s for s in g.seeds if not seeds or s in seeds)
            if not (kept_envs and kept_methods and kept_seeds):
                continue  # a grid the flags empty is dropped (an empty Grid is refused on construction)
            g = replace(g, envs=kept_envs, methods=kept_methods, seeds=kept_seeds, preset=preset or g.preset,
                        episodes=g.episodes if episodes is None else episodes)
            grids.append(merge_overrides(g, extra))
        if not grids:
            raise UserError(f"--envs / --methods / --seeds leave no trial of {spec_file}; check the names.")
        spec = replace(spec, grids=tuple(grids))
    else:
        if not envs:
            raise UserError("nothing to sweep: pass --envs ENV... (and --methods, --seeds) or --spec FILE.")
        spec = SweepSpec(grids=(Grid(envs=tuple(envs), methods=tuple(methods) or ("digail",),
                                     seeds=tuple(seeds) or (0,), preset=preset, episodes=episodes,
                                     overrides=extra),))
    if search is not None or spec.search is not None:
        base = spec.search or SearchSpec()
        if search not in (None, "optuna"):
            raise UserError(f"unknown search {search!r}; the search available is optuna.")
        spec = replace(spec, search=replace(base, trials=trials or base.trials, metric=metric or base.metric,
                                            mode=mode or base.mode))
    return spec.with_flags(retries=retries, cpus_per_trial=cpus_per_trial, gpus_per_trial=gpus_per_trial)
