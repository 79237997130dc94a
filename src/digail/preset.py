"""The presets: one TOML file per setting in `presets/` (each environment's settings, the paper's own per
environment, and a tiny `smoke`), each departure from the defaults with why and where it was measured, read once
into complete `Preset`s of the dataclasses in `digail.config`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from digail.config import TrainConfig, VAEConfig
from digail.errors import UserError


@dataclass(frozen=True)
class Preset:
    """A complete setting of the VAE and the trainer (an environment's, the paper's, or the defaults)."""

    vae: VAEConfig
    train: TrainConfig
    eval_episodes: int = 300
    """episodes for `digail evaluate` (paper: 300)"""


PRESET_DIR = Path(__file__).resolve().parent / "presets"
"""One TOML file per preset: `<name>.toml` states what departs from the defaults (or from the preset it
`extends`), each departure as `field = { value = ..., why = "one line", see = "where it was measured" }` under the
table of its config (`[vae]`, `[train]`, `[train.ppo]`; `Preset`'s own fields at the top)."""


@dataclass(frozen=True)
class Departure:
    """One setting of a preset that differs from what it builds on."""

    key: str
    """dotted field path from `Preset`, e.g. `train.ppo.batch_size`"""
    value: Any
    why: str
    """the reason, one line"""
    see: str
    """where it was measured (a docs link), or the source it comes from"""


@dataclass(frozen=True)
class PresetFile:
    """A preset as its file states it."""

    name: str
    about: str
    extends: str | None
    departures: tuple[Departure, ...]


def _departures(table: dict[str, Any], prefix: str, where: Path) -> list[Departure]:
    out: list[Departure] = []
    for key, entry in table.items():
        if not isinstance(entry, dict):
            raise UserError(f"{where}: {prefix}{key} must be a table {{ value = ..., why = ..., see = ... }} or a "
                            "config's section.")
        if "value" in entry:
            if set(entry) != {"value", "why", "see"} or not str(entry["why"]).strip():
                raise UserError(f"{where}: {prefix}{key} needs exactly value, a non-empty why and see.")
            out.append(Departure(prefix + key, entry["value"], str(entry["why"]), str(entry["see"])))
        else:
            out += _departures(entry, f"{prefix}{key}.", where)
    return out


def read_preset_file(path: Path) -> PresetFile:
    """The about line, base preset and departures of one preset file."""
    import tomllib

    with open(path, "rb") as f:
        data = tomllib.load(f)
    about, extends = data.pop("about", ""), data.pop("extends", None)
    return PresetFile(path.stem, str(about), extends, tuple(_departures(data, "", path)))


def _apply(obj: Any, values: dict[str, Any], where: str, prefix: str = "") -> Any:
    """`obj` (a config dataclass) with the dotted `values` set, each nested config rebuilt once with all of its
    own values (so its checks see the finished combination)."""
    fields = {f.name: f for f in dataclasses.fields(obj)}
    own: dict[str, Any] = {}
    nested: dict[str, dict[str, Any]] = {}
    for key, value in values.items():
        head, _, rest = key.partition(".")
        if head not in fields:
            raise UserError(f"preset {where}: unknown setting {prefix + key!r}; fix its name or remove it.")
        if rest:
            nested.setdefault(head, {})[rest] = value
        else:
            own[head] = tuple(value) if isinstance(value, list) and "tuple" in str(fields[head].type) else value
    for head, sub in nested.items():
        current = getattr(obj, head)
        if not dataclasses.is_dataclass(current):
            raise UserError(f"preset {where}: {prefix + head} has no settings of its own.")
        own[head] = _apply(current, sub, where, f"{prefix}{head}.")
    return dataclasses.replace(obj, **own)


def _load_presets(folder: Path) -> tuple[dict[str, Preset], dict[str, PresetFile]]:
    files = {p.stem: read_preset_file(p) for p in sorted(folder.glob("*.toml"))}
    built: dict[str, Preset] = {}

    def build(name: str, seen: tuple[str, ...] = ()) -> Preset:
        if name in built:
            return built[name]
        if name not in files or name in seen:
            raise UserError(f"preset {seen[-1] if seen else name!r} extends {name!r}, which "
                            f"{'extends it in turn' if name in seen else 'does not exist'}.")
        spec = files[name]
        base = build(spec.extends, (*seen, name)) if spec.extends else Preset(VAEConfig(), TrainConfig())
        built[name] = _apply(base, {d.key: d.value for d in spec.departures}, name)
        return built[name]

    for name in files:
        build(name)
    return built, files


PRESETS, PRESET_FILES = _load_presets(PRESET_DIR)
"""Every preset by name (`PRESET_FILES`: what each file states, for the docs' table)."""


PAPER = "paper"
"""`--preset paper`: the paper's own settings of the run's environment, the preset `paper-<env's preset>`"""


def preset_name(name: str, env_preset: str | None) -> str:
    """The preset file `name` asks for: `paper` becomes the paper's settings of the env whose own preset is
    `env_preset`; an unknown name is one `UserError` sentence."""
    if name == PAPER:
        if env_preset is None or f"{PAPER}-{env_preset}" not in PRESETS:
            raise UserError("--preset paper needs an environment whose settings the paper's Table 3 gives ("
                            + ", ".join(sorted(n[len(PAPER) + 1:] for n in PRESETS if n.startswith(PAPER + "-")))
                            + "); pass --env or a dataset of one, or name the preset.")
        name = f"{PAPER}-{env_preset}"
    if name not in PRESETS:
        raise UserError(f"unknown preset {name!r}; choose one of {', '.join(sorted([*PRESETS, PAPER]))}.")
    return name


def get_preset(name: str, env_preset: str | None = None) -> Preset:
    """The preset called `name` (`paper`: that of the env whose own preset is `env_preset`;
    `digail.envs.registry.env_preset` names an env's own)."""
    return PRESETS[preset_name(name, env_preset)]


def resolve_preset(name: str | None, env_preset: str | None) -> Preset:
    """The preset called `name`, else the env's own (`env_preset`, from its registry entry:
    `digail.envs.registry.env_preset`), else the defaults for an env without one."""
    if name is None:
        if env_preset is None:
            return Preset(VAEConfig(), TrainConfig())
        name = env_preset
    return get_preset(name, env_preset)
