"""digail: Directed-Info GAIL (Sharma et al., ICLR 2019).

Learns, from unsegmented expert demonstrations, a segmentation into sub-tasks, one policy per sub-task and a
macro-policy that switches between them. Importing the package registers its Gymnasium environments.

The public API lives at the top level (`digail.pretrain`, `digail.segment`, `digail.train`, `digail.evaluate`,
`digail.load_dataset`, `digail.Trajectory`, ...). Each name is the object of its home module (listed in
`_PUBLIC`), imported on first use, so `import digail` does not pay for the training code; the deep paths such as
`digail.algos.vae_pretrain.pretrain` keep working and are the same objects.
"""

from __future__ import annotations

import importlib
import os
import signal
import sys
import threading
from typing import TYPE_CHECKING, Any


def _stopped_while_importing(signum: int, frame: Any) -> None:
    sys.stderr.write("digail: stopped by SIGINT before it began; nothing was written.\n")
    os._exit(128 + signum)


# The `digail` command: Ctrl-C while the package itself still imports (its first second) ends the command with one
# line instead of a traceback; `digail.cli.main` takes over from there. A Python session importing digail keeps
# its own Ctrl-C.
_EARLY = (os.path.basename(sys.argv[0] if sys.argv else "") == "digail"
          and threading.current_thread() is threading.main_thread()  # where signal handlers may be set
          and signal.getsignal(signal.SIGINT) is signal.default_int_handler)
if _EARLY:
    signal.signal(signal.SIGINT, _stopped_while_importing)

from digail.data.trajectory import Trajectory  # noqa: E402  (after the Ctrl-C guard above)
from digail.envs import register_envs as _register_envs  # noqa: E402  (after the Ctrl-C guard above)
from digail.errors import UserError  # noqa: E402  (after the Ctrl-C guard above)
from digail.version import __version__  # noqa: E402  (after the Ctrl-C guard above)

if TYPE_CHECKING:  # what the lazy names below resolve to, for type checkers and editors
    from digail.algos.decode import segment
    from digail.algos.directed_info_gail import train
    from digail.algos.vae_pretrain import pretrain
    from digail.checkpoint import load_model, save_model
    from digail.config import TrainConfig, VAEConfig
    from digail.data.minari_io import Dataset, load_dataset
    from digail.eval.composition import compose, compose_order
    from digail.eval.returns import evaluate
    from digail.eval.segmentation import segmentation_metrics
    from digail.nets.vae import HierarchicalPolicy
    from digail.preset import get_preset

_register_envs()
if _EARLY:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# public name -> the module that defines it (imported when the name is first looked up)
_PUBLIC: dict[str, str] = {
    "load_dataset": "digail.data.minari_io",
    "Dataset": "digail.data.minari_io",
    "VAEConfig": "digail.config",
    "TrainConfig": "digail.config",
    "get_preset": "digail.preset",
    "pretrain": "digail.algos.vae_pretrain",
    "segment": "digail.algos.decode",
    "train": "digail.algos.directed_info_gail",
    "evaluate": "digail.eval.returns",
    "compose": "digail.eval.composition",
    "compose_order": "digail.eval.composition",
    "segmentation_metrics": "digail.eval.segmentation",
    "HierarchicalPolicy": "digail.nets.vae",
    "save_model": "digail.checkpoint",
    "load_model": "digail.checkpoint",
}

__all__ = [
    "Dataset", "HierarchicalPolicy", "TrainConfig", "Trajectory", "UserError", "VAEConfig", "__version__", "compose",
    "compose_order", "evaluate", "get_preset", "load_dataset", "load_model", "pretrain", "save_model", "segment",
    "segmentation_metrics", "train",
]


def __getattr__(name: str) -> Any:
    if name not in _PUBLIC:
        raise AttributeError(f"module 'digail' has no attribute {name!r}")
    value = getattr(importlib.import_module(_PUBLIC[name]), name)
    globals()[name] = value  # looked up once; later accesses skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
