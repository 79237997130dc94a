"""Small shared helpers: seeding, torch threads and devices, run folder names, memory, progress bars, MuJoCo's
renderer. Writing output folders and files safely is `digail.fsio`."""

from __future__ import annotations

import contextlib
import ctypes.util
import os
import random
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from digail.errors import UserError

if TYPE_CHECKING:
    import torch


def seed_everything(seed: int) -> np.random.Generator:
    """Seed Python, NumPy and torch; return a fresh NumPy generator for the caller's own draws."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    import torch  # here, not at the top: `import digail` reaches this module and should not pay for torch

    torch.manual_seed(seed)
    return np.random.default_rng(seed)


def set_torch_threads(n: int = 1) -> None:
    """2x64 nets gain nothing from a second thread and get much noisier under load; default to one."""
    import torch

    torch.set_num_threads(n)


def keep_heap_pages() -> bool:
    """Have glibc's malloc keep freed memory for the next allocation instead of returning it to the system: a
    SAC update on the CPU allocates and frees a few MB of temporaries (512 KB each for 2x256x256 activations), and
    glibc's defaults hand them back and page-fault them in again on every update (about 850 faults, a fifth of an
    update with 256x256 critics, measured). Blocks under 32 MB then come from the heap, and up to 256 MB of free heap
    is kept. Returns whether it applied (glibc only; elsewhere nothing changes)."""
    import ctypes
    import platform

    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        m_trim_threshold, m_mmap_threshold = -1, -3  # mallopt's parameter numbers (malloc.h)
        return bool(libc.mallopt(m_mmap_threshold, 32 << 20)) and bool(libc.mallopt(m_trim_threshold, 256 << 20))
    except (OSError, AttributeError):
        return False


def resolve_device(device: str) -> torch.device:
    """`auto` picks CUDA when present, else CPU; an unavailable explicit device is a user error."""
    import torch

    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise UserError(f"--device {device} was asked for but CUDA is not available; use --device cpu.")
    try:
        return torch.device(device)
    except RuntimeError as exc:
        raise UserError(f"unknown device {device!r}; use cpu, cuda or auto.") from exc


def default_run_dir(env_id: str, method: str, seed: int, root: str | Path = "runs") -> Path:
    """`runs/<env>__<method>__s<seed>__<time>` with the env id made filesystem-safe."""
    safe_env = env_id.replace("/", "-")
    stamp = time.strftime("%Y%m%d-%H%M%S")
    return Path(root) / f"{safe_env}__{method}__s{seed}__{stamp}"


def available_memory() -> int | None:
    """Bytes of memory this machine can still hand out (Linux's MemAvailable, else free pages), or None when
    unknown: what a large allocation is checked against before it is tried, so that a size no machine has is
    one sentence rather than a MemoryError."""
    with contextlib.suppress(OSError, ValueError, IndexError), open("/proc/meminfo") as f:
        for line in f:
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    with contextlib.suppress(AttributeError, ValueError, OSError):
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    return None


def human_bytes(n: float) -> str:
    """`n` bytes as a short text with a binary unit (12.0 GiB)."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.1f} PiB"


def one_line(exc: BaseException) -> str:
    """An exception's message as one line without a final full stop (for `UserError` sentences)."""
    text = " ".join(str(exc).split())
    return text.rstrip(".") if text else type(exc).__name__


PROGRESS_INTERVAL_S = 0.5
"""seconds between redraws of a progress bar on a terminal"""
PROGRESS_LOG_INTERVAL_S = 60.0
"""seconds between progress lines off a terminal (a log file, CI, nohup, a job scheduler)"""


class _LineStream:
    """What tqdm writes, as one line per update: off a terminal a carriage-return redraw piles up on one
    never-ending line of the log, where a line per update reads (and greps) as a log does."""

    def __init__(self, stream: Any) -> None:
        self.stream = stream

    def write(self, text: str) -> int:
        line = text.replace("\r", "").rstrip()
        if line:
            self.stream.write(line + "\n")
        return len(text)

    def flush(self) -> None:
        self.stream.flush()


def progress_bar(total: int, enabled: bool = True, desc: str = "VAE", unit: str = "epoch", initial: int = 0) -> Any:
    """The tqdm bar of a long loop (disabled, drawing nothing, when `enabled` is False).

    On a terminal it redraws every `PROGRESS_INTERVAL_S`. Off one (stderr is a file or a pipe) it writes a line
    at its start, at most one every `PROGRESS_LOG_INTERVAL_S` and one at its end, rather than a redraw twice a
    second that fills a log with thousands of updates. Set postfixes with `refresh=False`: a forced refresh
    would draw on every call."""
    import sys

    from tqdm.auto import tqdm
    from tqdm.autonotebook import tqdm as chosen

    stream = sys.stderr
    interactive = stream is not None and hasattr(stream, "isatty") and stream.isatty()
    notebook = chosen.__module__ == "tqdm.notebook"  # a Jupyter widget, which draws in place
    enabled = enabled and total > 0  # a loop over nothing (e.g. no VAE epochs before the polish) shows nothing
    if interactive or notebook or not enabled:
        return tqdm(total=total, initial=initial, desc=desc, unit=unit, mininterval=PROGRESS_INTERVAL_S,
                    dynamic_ncols=True, disable=not enabled)
    # miniters=1: the clock is read at every update, so a line comes once a minute whatever the pace (tqdm's
    # adaptive skipping would delay it when the loop slows down, and its monitor thread would add extra lines)
    return tqdm(total=total, initial=initial, desc=desc, unit=unit, file=_LineStream(stream), miniters=1,
                mininterval=PROGRESS_LOG_INTERVAL_S)


def ensure_offscreen_gl() -> str:
    """Set `MUJOCO_GL` for headless rendering unless the user chose one: `egl`, or `osmesa` where no EGL library
    is installed but OSMesa is (with neither, `egl`, whose error then names what is missing).

    Only effective before MuJoCo is first imported, so the CLI calls it first thing. Returns the value in force.
    """
    if "MUJOCO_GL" not in os.environ:
        has_egl = ctypes.util.find_library("EGL") is not None
        has_osmesa = ctypes.util.find_library("OSMesa") is not None
        os.environ["MUJOCO_GL"] = "egl" if has_egl or not has_osmesa else "osmesa"
    return os.environ["MUJOCO_GL"]


MUJOCO_GL_VALUES = ("egl", "osmesa", "glfw", "glx", "disable", "disabled", "off", "false", "0", "enable", "enabled",
                    "on", "true", "1", "")
"""what MuJoCo accepts in `MUJOCO_GL` on Linux (anything else fails its import)"""


def mujoco_gl_error(render_error: BaseException | None = None) -> UserError | None:
    """Why MuJoCo cannot start (or, given the exception, render) under this process's `MUJOCO_GL`, as one
    `UserError` sentence; None when it imports and no `render_error` is given.

    MuJoCo reads the variable when first imported and fails with a RuntimeError (an unknown value) or an
    AttributeError deep in PyOpenGL (osmesa without its library); with another PyOpenGL platform already chosen
    in the process it imports and fails at the first frame instead. Callers that see either turn it into this
    sentence."""
    gl = os.environ.get("MUJOCO_GL", "")
    value = gl.lower().strip()
    fix = "unset MUJOCO_GL (digail then picks egl, or osmesa where only it is installed) or set it to egl"
    problem = render_error
    try:
        import mujoco  # noqa: F401
    except Exception as exc:  # noqa: BLE001  (any failure of the import means the same to the user)
        problem = exc
    if problem is None:
        return None
    if sys.platform.startswith("linux") and value not in MUJOCO_GL_VALUES:
        return UserError(f"MUJOCO_GL={gl!r} is not a renderer MuJoCo knows (egl, osmesa, glfw); {fix}.")
    if value in ("osmesa", "egl") and ctypes.util.find_library("OSMesa" if value == "osmesa" else "EGL") is None:
        return UserError(f"MUJOCO_GL={value} but the {'OSMesa' if value == 'osmesa' else 'EGL'} library is not "
                         f"installed; install it or {fix.replace(' or set it to egl', '')}.")
    return UserError(f"MuJoCo cannot {'render' if problem is render_error else 'start'} with MUJOCO_GL={gl!r} "
                     f"({type(problem).__name__}: {one_line(problem)}); {fix}.")


def die_with_parent() -> None:
    """In a child process (`preexec_fn`): get SIGKILL when the parent dies (Linux; elsewhere nothing), so that no
    helper process outlives the command that started it."""
    with contextlib.suppress(Exception):
        import signal

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
