"""Self-contained, pickle-free checkpoints of a `HierarchicalPolicy`.

A checkpoint is one `torch.save` file holding only tensors and plain Python data, so it loads with
`torch.load(..., weights_only=True)`: the state_dict (normaliser statistics included, they are buffers), what is
needed to rebuild the model (observation size, number of codes, action spec, hidden sizes), the environment id,
what produced it (`kind`: "vae", "digail", "gail", ...), the digail version and the resolved config as a JSON
string. Run folders keep it as `model.pt` beside `config.json`, whose one schema (`run_config`) lives here too,
below every layer that writes a run folder (the commands and the expert trainer).
"""

from __future__ import annotations

import io
import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from digail.errors import UserError
from digail.fsio import atomic_write_bytes
from digail.nets.policy import ActionSpec
from digail.nets.vae import HierarchicalPolicy

FORMAT = "digail-model"
FORMAT_VERSION = 1
MODEL_FILE = "model.pt"
CONFIG_FILE = "config.json"


def save_model(path: str | Path, model: HierarchicalPolicy, *, kind: str, config: dict[str, Any],
               env_id: str | None, extra: dict[str, Any] | None = None) -> Path:
    """Write `model` and its metadata to `path` atomically (a temporary file renamed over it).

    Args:
        path: the file to write, or a folder (then `folder/model.pt`).
        model: the hierarchical policy; its normaliser statistics travel in the state_dict.
        kind: what produced the model, e.g. "vae" or "digail".
        config: the resolved configuration (JSON-serialisable), stored as a JSON string.
        env_id: the Gymnasium id the demonstrations came from, or None when unknown.
        extra: more weights-only data to keep (tensors, numbers, strings, lists, dicts), e.g. an optimiser
            state_dict for resuming; returned under `meta["extra"]`.

    Returns:
        The path of the written file.
    """
    from digail.version import __version__

    path = Path(path)
    if path.is_dir():
        path = path / MODEL_FILE
    payload = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "digail_version": __version__,
        "kind": kind,
        "env_id": env_id,
        "obs_dim": int(model.obs_dim),
        "codes": int(model.codes),
        "action_discrete": bool(model.action.discrete),
        "action_dim": int(model.action.dim),
        "hidden": [int(h) for h in model.hidden],
        "learn_prior": bool(model.learn_prior),
        "decoder_obs": None if model.decoder_obs is None else [int(i) for i in model.decoder_obs],
        "config_json": json.dumps(config, default=str),
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "extra": extra or {},
    }
    buf = io.BytesIO()
    torch.save(payload, buf)
    atomic_write_bytes(path, buf.getvalue())
    return path


def load_weights(path: str | Path, what: str = "checkpoint", device: str | torch.device = "cpu") -> Any:
    """`torch.load(path, weights_only=True)` onto `device`, every failure one `UserError` sentence.

    A truncated or corrupt file, text, or a pickle holding anything but tensors and plain data (a hostile one
    included: nothing in it runs) all read as "not a digail checkpoint". Torch's own message is not repeated: it
    suggests `weights_only=False`, which would execute whatever the file holds.
    """
    path = Path(path)
    try:
        with warnings.catch_warnings():
            # torch warns about a foreign file's pickle protocol before failing on it: the sentence below says it
            warnings.filterwarnings("ignore", message="Detected pickle protocol", category=UserWarning)
            return torch.load(path, map_location=device, weights_only=True)
    except (PermissionError, IsADirectoryError) as exc:
        raise UserError(f"cannot read {what} {path} ({exc.strerror.lower() if exc.strerror else 'unreadable'}); "
                        "check its permissions.") from None
    except FileNotFoundError:
        raise UserError(f"no {what} at {path}; pass the folder of a digail run.") from None
    except Exception:  # noqa: BLE001  (torch raises many types here: each means the same to the user)
        raise UserError(f"cannot read {what} {path}: it is corrupt, truncated or not a digail file (only "
                        "weights are ever loaded from it); re-create the run.") from None


def read_config(run: str | Path) -> dict[str, Any]:
    """RUN/config.json as a dict; a missing file gives {}, an unreadable or invalid one a `UserError` sentence."""
    path = Path(run) / CONFIG_FILE
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        where = f" (line {exc.lineno})" if isinstance(exc, json.JSONDecodeError) else ""
        raise UserError(f"{path} is not valid JSON{where}; restore it or re-create the run.") from None
    if not isinstance(data, dict):
        raise UserError(f"{path} does not hold a JSON object; restore it or re-create the run.")
    return data


CONFIG_SCHEMA = 1
"""version of the `config.json` layout below; bumped when a key changes meaning"""


def path_ref(value: str | Path | None) -> str | None:
    """A dataset or run reference as `config.json` stores it: an existing path made absolute (so a later command
    run from another directory finds it), anything else (a dataset id) as given."""
    if value is None or str(value) == "":
        return None
    path = Path(value)
    return str(path.resolve()) if path.exists() else str(value)


def run_config(*, kind: str, env_id: str | None, demos: str | Path | None, seed: int, preset: str | None = None,
               device: str | None = None, vae: Any = None, train: Any = None, vae_run: str | Path | None = None,
               args: Any = None, **extra: Any) -> dict[str, Any]:
    """The one schema of every run folder's `config.json` (and of the config inside its `model.pt`).

    Keys: `schema`, `kind` ("vae", "digail", "gail", "expert"), `method` (the same for trained policies),
    `env_id`, `demos` and `vae_run` (absolute paths or dataset ids, see `path_ref`), `seed`, `preset`, `device`,
    `digail_version`, `vae` and `train` (the resolved `VAEConfig` / `TrainConfig`, or None), `args` (the
    command's own arguments, what `--resume` rebuilds them from) and any command-specific extras (an expert's
    `steps` budget and `expert` recipe).
    """
    from digail.config import to_dict
    from digail.user_envs import recorded_spec
    from digail.version import __version__

    config: dict[str, Any] = {
        "schema": CONFIG_SCHEMA,
        "kind": kind,
        "method": kind if kind in ("digail", "gail") else None,
        "env_id": env_id,
        **({"env_spec": spec} if (spec := recorded_spec(env_id)) else {}),
        "demos": path_ref(demos),
        "vae_run": path_ref(vae_run),
        "seed": seed,
        "preset": preset,
        "device": device,
        "digail_version": __version__,
        "vae": to_dict(vae) if vae is not None else None,
        "train": to_dict(train) if train is not None else None,
        "args": to_dict(args) if args is not None else None,
    }
    config.update(extra)
    return config


def write_run_config(run_dir: Path, config: dict[str, Any]) -> Path:
    """Write `config` (from `run_config`) as RUN/config.json; returns the file."""
    from digail.fsio import write_json

    path = Path(run_dir) / CONFIG_FILE
    write_json(path, config)
    return path


def load_model(path: str | Path, device: str | torch.device = "cpu") -> tuple[HierarchicalPolicy, dict[str, Any]]:
    """Rebuild the model saved by `save_model`, in eval mode on `device`.

    Args:
        path: the checkpoint file, or a run folder holding `model.pt`.
        device: where to put the model.

    Returns:
        `(model, meta)` where `meta` has `kind`, `env_id`, `digail_version`, `obs_dim`, `codes`, `action`
        (an `ActionSpec`), `hidden`, `decoder_obs`, `config` (a dict) and `extra`.

    Raises:
        UserError: the file is missing, unreadable, not a digail checkpoint, or does not fit the model it describes.
    """
    path = Path(path)
    if path.is_dir():
        path = path / MODEL_FILE
    if not path.is_file():
        raise UserError(f"no model checkpoint at {path}; pass a run folder made by `digail pretrain` or "
                        "`digail train`.")
    payload = load_weights(path)
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise UserError(f"{path} is not a digail model checkpoint; pass the model.pt of a digail run folder.")
    if payload.get("format_version") != FORMAT_VERSION:
        raise UserError(f"checkpoint {path} has format version {payload.get('format_version')}, this digail reads "
                        f"version {FORMAT_VERSION}; re-create the run with this version.")
    try:
        action = ActionSpec(bool(payload["action_discrete"]), int(payload["action_dim"]))
        # "pi_obs": the key's name in model files written before it took the config's name
        decoder_obs = payload.get("decoder_obs", payload.get("pi_obs"))
        model = HierarchicalPolicy(int(payload["obs_dim"]), int(payload["codes"]), action,
                                   hidden=tuple(payload["hidden"]), learn_prior=bool(payload["learn_prior"]),
                                   decoder_obs=None if decoder_obs is None
                                   else (int(decoder_obs[0]), int(decoder_obs[1])))
        model.load_state_dict(payload["state_dict"])
        config = json.loads(payload["config_json"])
    except (KeyError, TypeError, RuntimeError, json.JSONDecodeError) as exc:
        raise UserError(f"checkpoint {path} is incomplete or does not match its model description ({exc}); "
                        "re-create the run.") from exc
    meta = {
        "kind": payload.get("kind"),
        "env_id": payload.get("env_id"),
        "digail_version": payload.get("digail_version"),
        "obs_dim": model.obs_dim,
        "codes": model.codes,
        "action": action,
        "hidden": model.hidden,
        "decoder_obs": model.decoder_obs,
        "config": config,
        "extra": payload.get("extra", {}),
    }
    return model.to(device).eval(), meta


# ------------------------------------------------------------------------------------- training state
def save_training_state(path: Path, state: dict[str, Any]) -> None:
    """Atomically write a trainer's full state (tensors, numbers, strings, nested dicts: weights_only-loadable)."""
    buf = io.BytesIO()
    torch.save(state, buf)
    atomic_write_bytes(Path(path), buf.getvalue())


def load_training_state(path: Path, device: str | torch.device = "cpu") -> dict[str, Any]:
    """What `save_training_state` wrote, loaded with `weights_only=True` (a broken file: one `UserError`)."""
    return load_weights(path, "training checkpoint", device)


def rng_state(gen: torch.Generator, np_rng: np.random.Generator) -> dict[str, Any]:
    """torch's global RNG, a torch generator and a NumPy PCG64 generator as checkpointable data (the NumPy
    state's 128-bit integers as strings, which `weights_only` loading accepts)."""
    st = np_rng.bit_generator.state
    return {"torch": torch.get_rng_state(), "gen": gen.get_state(),
            "numpy": {"state": str(st["state"]["state"]), "inc": str(st["state"]["inc"]),
                      "has_uint32": int(st["has_uint32"]), "uinteger": int(st["uinteger"])}}


def set_rng_state(state: dict[str, Any], gen: torch.Generator, np_rng: np.random.Generator) -> None:
    """Restore what `rng_state` captured."""
    torch.set_rng_state(state["torch"])
    gen.set_state(state["gen"])
    data = state["numpy"]
    st = dict(np_rng.bit_generator.state)
    st["state"] = {"state": int(data["state"]), "inc": int(data["inc"])}
    st["has_uint32"], st["uinteger"] = int(data["has_uint32"]), int(data["uinteger"])
    np_rng.bit_generator.state = st
