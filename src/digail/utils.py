"""Small shared helpers: seeding, run folders, atomic writes, torch threads."""

from __future__ import annotations

import contextlib
import ctypes.util
import json
import os
import random
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator
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


MIN_FREE_BYTES = 16 * 2**20
"""an output location with less free space than this is refused before the work starts"""


def check_writable(path: Path, flag: str = "--out") -> None:
    """Refuse, in one sentence, an output location that cannot be written: `path` itself when it is a folder,
    else the nearest folder above it that exists (where it will be created). Probes with a real temporary file,
    so read-only mounts count too (as root `os.access` says yes to everything), and checks free space."""
    path = Path(path)
    probe_dir = path if path.is_dir() or not path.exists() else path.parent  # a file is replaced from its folder
    while not probe_dir.exists() and probe_dir != probe_dir.parent:
        probe_dir = probe_dir.parent
    if not probe_dir.is_dir():
        raise UserError(f"cannot create {path}: {probe_dir} is a file, not a folder; choose another {flag}.")
    try:
        fd, probe = tempfile.mkstemp(prefix=".digail-write-probe-", dir=probe_dir)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        reason = (exc.strerror or type(exc).__name__).lower()
        raise UserError(f"cannot write to {probe_dir} ({reason}); choose another {flag} or fix its "
                        "permissions.") from None
    free = shutil.disk_usage(probe_dir).free
    if free < MIN_FREE_BYTES:
        raise UserError(f"only {free // 2**20} MiB free where {path} would be written; free some space or choose "
                        f"another {flag}.")
    limit = file_size_limit()
    if limit is not None and limit < MIN_FREE_BYTES:
        # checked up front: HDF5 (the datasets' format) crashes instead of reporting a write past the limit
        raise UserError(f"a file-size limit of {limit // 1024} KiB is in force (`ulimit -f`), too small for "
                        f"what {path} will hold; raise it or run without it.")


def file_size_limit() -> int | None:
    """The largest file this process may write, in bytes (`ulimit -f`), or None when unlimited or unknown."""
    try:
        import resource
    except ImportError:  # not on this platform
        return None
    soft, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
    return None if soft == resource.RLIM_INFINITY else int(soft)


def check_new_dir(path: Path, force: bool, hint: str = "") -> None:
    """Refuse to overwrite an existing output folder unless `force`, and an output that cannot be written.

    `hint` is appended to the refusal (e.g. how to continue an unfinished run instead). With `force` the existing
    output must be one `--force` may replace (`check_replaceable`)."""
    path = Path(path)
    exists = path.exists() or path.is_symlink()
    if exists and not force:
        what = "folder" if path.is_dir() else "file"
        raise UserError(f"output {what} {path} already exists; choose another --out or pass --force{hint}.")
    if exists:
        check_replaceable(path)
    check_not_locked(path)  # --force never replaces a folder another command is writing
    check_writable(path)


MARKER = ".digail"
"""the file digail writes into every run, sweep and dataset folder it makes: what lets `--force` replace one"""


def write_marker(folder: Path) -> None:
    """Mark `folder` as one digail made (`MARKER`), so a later `--force` may replace it."""
    (Path(folder) / MARKER).write_text("made by digail: `digail ... --force` may replace this folder\n")


def digail_made(folder: Path) -> bool:
    """Whether `folder` is one digail made: it holds `MARKER`, or (folders from before the marker) a run's
    config.json (a JSON object naming `env_id` and `seed`), a dataset's data/metadata.json with digail's record, or
    a sweep's sweep.json beside its trials/ folder. An empty folder (a lock file aside) counts too: replacing it
    loses nothing."""
    folder = Path(folder)
    if (folder / MARKER).is_file():
        return True
    try:
        if not any(child.name != LOCK_FILE for child in folder.iterdir()):
            return True
    except OSError:
        return False
    run = _json_object(folder / "config.json")
    if run is not None and "env_id" in run and "seed" in run:
        return True
    dataset = _json_object(folder / "data" / "metadata.json")
    if dataset is not None and "digail" in dataset and (folder / "data" / "main_data.hdf5").is_file():
        return True
    return (folder / "trials").is_dir() and _json_object(folder / "sweep.json") is not None


def _json_object(path: Path) -> dict[str, Any] | None:
    try:
        if not path.is_file() or path.stat().st_size > 16 * 2**20:
            return None
        data = json.loads(path.read_bytes())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def check_replaceable(path: Path, flag: str = "--out") -> None:
    """Refuse, in one sentence, an existing output that `--force` must not replace: anything but a folder digail
    made (`digail_made`), and whatever its content the current directory, a folder above it, the home folder or a
    filesystem root. A symbolic link is judged by what it points to."""
    path = Path(path)
    try:
        real = path.resolve()
    except (OSError, RuntimeError):  # a loop of links
        raise UserError(f"{path} is a link that leads nowhere; remove it or choose another {flag}.") from None
    if real == Path(real.anchor) or real == Path.home().resolve():
        what = "a filesystem root" if real == Path(real.anchor) else "the home folder"
        raise UserError(f"--force would delete {path}, {what}; choose another {flag}.")
    cwd = Path.cwd().resolve()
    if real == cwd or real in cwd.parents:
        here = "the current directory" if real == cwd else "a folder holding the current directory"
        raise UserError(f"--force would delete {path}, {here}; choose another {flag}.")
    if not real.exists():
        raise UserError(f"{path} is a link to nothing; remove it or choose another {flag}.")
    if not real.is_dir():
        raise UserError(f"{path} is a file, and --force replaces only a folder digail made; move the file away or "
                        f"choose another {flag}.")
    if not digail_made(real):
        raise UserError(f"{path} is not a folder digail made (no {MARKER} file, run config or dataset record in "
                        f"it), and --force replaces only those; move its files away or choose another {flag}.")


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


def umask() -> int:
    """The process's file-mode creation mask."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def remove_path(path: Path) -> None:
    """Remove a folder tree or a file (or nothing, when absent)."""
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


LOCK_FILE = ".digail.lock"
"""the file inside a run folder that a command writing the folder holds an exclusive `flock` on"""
_HELD: dict[str, int] = {}
"""run folders this process holds (real path -> the lock file's descriptor)"""


@contextlib.contextmanager
def run_dir_lock(folder: Path) -> Iterator[Path]:
    """Hold the existing run folder `folder` for writing while the block runs: one writer per folder.

    An exclusive `flock` on `folder/.digail.lock`, so a second command that would write the same folder (a
    `train --force` on a live run, an `evaluate` during a training) is refused in one sentence instead of
    clobbering it. The kernel drops the lock when its process dies, so a lock file left by a killed process
    blocks nothing; the file is removed on release. Re-entrant within a process; a no-op where `fcntl` does not
    exist."""
    folder = Path(folder)
    key = os.path.realpath(folder)
    try:
        import fcntl
    except ImportError:  # not POSIX: no locking
        yield folder
        return
    if key in _HELD:
        yield folder
        return
    fd = _lock_file(folder, fcntl)
    _HELD[key] = fd
    try:
        yield folder
    finally:
        del _HELD[key]
        with signals_deferred():
            if _same_file(fd, folder / LOCK_FILE):  # still ours (the folder may have been swapped away)
                with contextlib.suppress(OSError):
                    os.unlink(folder / LOCK_FILE)
            os.close(fd)


def _same_file(fd: int, path: Path) -> bool:
    try:
        st, fst = os.stat(path), os.fstat(fd)
    except OSError:
        return False
    return (st.st_ino, st.st_dev) == (fst.st_ino, fst.st_dev)


def _lock_file(folder: Path, fcntl: Any) -> int:
    path = folder / LOCK_FILE
    while True:
        try:  # never through a link: the lock file is created in the run folder, nowhere else
            fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o666)
        except OSError as exc:  # a folder, a link or an unreadable file in the lock file's place
            if path.is_dir() or path.is_symlink():
                what = "a link" if path.is_symlink() else "a folder"
                raise UserError(f"{path} is {what}, not digail's lock file; remove it and run the command "
                                "again.") from None
            reason = (exc.strerror or type(exc).__name__).lower()
            raise UserError(f"cannot open the lock file {path} ({reason}); remove it or fix its permissions.") \
                from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:  # held by a live process
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip()
            os.close(fd)
            who = f" (process {holder})" if holder.isdigit() else ""
            raise UserError(f"{folder} is being written by another digail command{who}; wait for it to finish "
                            "or choose another folder.") from None
        except OSError:  # a filesystem without locks (some network mounts): written as before, unguarded
            return fd
        # the previous holder removes the file on release: a lock taken on a file no longer in place is retried
        if _same_file(fd, path):
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            return fd
        os.close(fd)


def check_not_locked(folder: Path) -> None:
    """Refuse, in one sentence, a folder another process is writing (`run_dir_lock`); takes no lock."""
    if Path(folder).is_dir() and not Path(folder).is_symlink():
        with run_dir_lock(folder):
            pass


@contextlib.contextmanager
def fresh_dir(path: Path, force: bool, hint: str = "") -> Iterator[Path]:
    """Create the output folder `path` for a command that writes in place (resumable training) and hold it
    (`run_dir_lock`) while the block runs: refused when it exists without `force`; with `force`, whatever was
    there (old eval.json, segmentation.json, a file) goes first, so nothing old sits beside the new results,
    unless another command is writing it."""
    path = Path(path)
    check_new_dir(path, force, hint)
    if force and (path.is_symlink() or (path.exists() and not path.is_dir())):
        remove_path(path)
    try:
        path.mkdir(parents=True, exist_ok=force)
    except FileExistsError:  # made by another command since the check
        raise UserError(f"output folder {path} already exists; choose another --out or pass --force{hint}.") \
            from None
    with run_dir_lock(path):
        for child in path.iterdir():  # --force: the old files go, the lock stays
            if child.name != LOCK_FILE:
                remove_path(child)
        write_marker(path)
        yield path


@contextlib.contextmanager
def atomic_dir(final: Path, force: bool = False) -> Iterator[Path]:
    """Yield a temporary sibling folder; rename it to `final` only if the block succeeds.

    Nothing half-written is left behind on error, Ctrl-C or SIGTERM (the CLI turns it into an exception): the
    temporary folder is removed. It gets the permissions of a plain `mkdir` (not mkdtemp's private 0700), so a
    folder looks the same whichever command made it. With `force` an existing folder or file at `final` is
    replaced only once the new one is complete.
    """
    final = Path(final)
    check_new_dir(final, force)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.tmp-", dir=final.parent))
    try:
        tmp.chmod(0o777 & ~umask())
        write_marker(tmp)
        yield tmp
    except BaseException:
        with signals_deferred():
            shutil.rmtree(tmp, ignore_errors=True)
        raise
    if (final.exists() or final.is_symlink()) and not force:  # made by another command meanwhile
        shutil.rmtree(tmp, ignore_errors=True)
        raise UserError(f"output {final} appeared while this command ran; choose another --out or pass --force.")
    with contextlib.ExitStack() as held:
        if final.is_dir() and not final.is_symlink():
            try:
                held.enter_context(run_dir_lock(final))  # a folder another command is writing is never swapped away
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
        with signals_deferred():  # the swap and its clean-up are not cut in half by a signal
            old = None
            try:
                if final.exists() or final.is_symlink():
                    old = Path(tempfile.mkdtemp(prefix=f".{final.name}.old-", dir=final.parent))
                    os.replace(final, old / "x")  # out of the way first, so a failure never loses both
                os.replace(tmp, final)
            except BaseException:
                if old is not None and (old / "x").exists() and not final.exists():
                    os.replace(old / "x", final)
                shutil.rmtree(tmp, ignore_errors=True)
                raise
            finally:
                if old is not None:
                    remove_path(old)


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """Hold SIGINT and SIGTERM until the block is done (clean-ups that must not stop half-way); they are
    delivered right after. A no-op off the main thread or where signal masks do not exist."""
    import signal
    import threading

    mask = {signal.SIGINT, signal.SIGTERM}
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, mask)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write to a temporary file in the same folder, then rename over `path`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o666 & ~umask())  # mkstemp's files are private; a plain open() would not be
        os.replace(tmp, path)
    except BaseException:
        with signals_deferred(), contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_json(path: Path, obj: Any) -> None:
    """Atomically write `obj` as indented JSON (NumPy scalars and arrays converted)."""

    atomic_write_bytes(Path(path), (json.dumps(obj, indent=2, default=json_default) + "\n").encode())


def json_default(o: Any) -> Any:
    """`json.dumps(default=...)` for NumPy scalars and arrays and paths."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


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
