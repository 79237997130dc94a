"""Output folders and files, written safely: checks that refuse an output that cannot be written or must not be
replaced, one writer per run folder (`run_dir_lock`), and folders and files that appear whole or not at all. Every
command that writes goes through these, so they share one marker file and one lock-file convention.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import stat
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from digail.errors import OldOutputLeft, UserError

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


def check_new_dir(path: Path, force: bool, hint: str = "",
                  protected: Sequence[tuple[str | os.PathLike[str], str]] = ()) -> None:
    """Refuse to overwrite an existing output folder unless `force`, and an output that cannot be written.

    `hint` is appended to the refusal (e.g. how to continue an unfinished run instead). Refused whatever `force`:
    a path that is, lies inside or holds one of the `protected` (path, what it is) pairs (what the command reads;
    `check_clear_of`), a FIFO, a device or a socket. With `force` the existing output must be one `--force` may
    replace (`check_replaceable`)."""
    path = Path(path)
    check_clear_of(path, protected)
    with contextlib.suppress(OSError):
        special = file_kind(os.stat(path).st_mode)  # a link is judged by what it points to
        if special is not None:
            raise UserError(f"--out {path} is {special}, not a file or folder digail wrote; choose another --out.")
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
    except (OSError, ValueError, RecursionError):  # RecursionError: nested beyond the parser's depth, not digail's
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


def check_clear_of(out: Path, protected: Sequence[tuple[str | os.PathLike[str], str]], flag: str = "--out") -> None:
    """Refuse, in one sentence, an output that is, lies inside or holds one of the `protected` (path, what it is)
    pairs (links resolved): what a command reads, or a run's files, is never written over."""
    real = Path(os.path.realpath(out))
    for path, what in protected:
        other = Path(os.path.realpath(path))
        relation = ("is" if real == other else "is inside" if other in real.parents else
                    "holds" if real in other.parents else None)
        if relation is not None:
            named = "" if relation == "is" else f", {path}"
            raise UserError(f"{flag} {out} {relation} {what}{named}; digail never writes over what it reads or a "
                            f"run's files, choose another {flag}.")


def check_output(out: Path, kind: Literal["file", "folder"], force: bool, *,
                 protected: Sequence[tuple[str | os.PathLike[str], str]] = (), flag: str = "--out",
                 ours: Callable[[Path], bool] | None = None, ours_what: str = "an output digail wrote",
                 writes: str | None = None, example: str = "out") -> None:
    """The one rule for a path digail is told to write (`--out` of every command), checked before any work.

    Refused, in one sentence: a path that is, lies inside or holds one of the `protected` (path, what it is) pairs
    (what the command reads, a run's files; links resolved); a symbolic link (even one to nothing), a FIFO, a device
    or a socket, since the output is written only as a file or folder of its own; a folder where a file goes or a
    file where a folder goes; an existing output without `force`, and with it anything but what digail wrote (a
    folder `check_replaceable` accepts, a file `ours` recognises: e.g. an earlier page or export of the same kind);
    a place that cannot be written.

    Args:
        kind: what the command writes at `out`.
        ours: for `kind` "file", whether an existing file is one digail wrote (without it no file is replaced).
        ours_what: the words for such files in the refusal, e.g. "a report page digail wrote".
        writes: what the command writes, in the refusal of a folder for a file and the reverse (e.g. "--export
            csv writes a file").
        example: a file name to suggest inside a folder given where a file goes.
    """
    out = Path(out)
    check_clear_of(out, protected, flag)
    try:
        st = os.lstat(out)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise UserError(f"cannot look at {flag} {out} ({(exc.strerror or type(exc).__name__).lower()}); choose "
                        f"another {flag}.") from None
    if st is not None:
        if stat.S_ISLNK(st.st_mode):
            raise UserError(f"{flag} {out} is a symbolic link; digail writes only a file or folder of its own, never "
                            f"through a link: remove the link or choose another {flag}.")
        special = file_kind(st.st_mode)
        if special is not None:
            raise UserError(f"{flag} {out} is {special}, not a file or folder digail wrote; choose another {flag}.")
        is_dir = stat.S_ISDIR(st.st_mode)
        if kind == "folder" and not is_dir:
            raise UserError(f"{flag} {out} is a file, but {writes or 'a folder is written there'}; choose a new "
                            "folder name.")
        if kind == "file" and is_dir:
            raise UserError(f"{flag} {out} is a folder, but {writes or 'a file is written there'}; give a file name "
                            f"such as {out / example}.")
        if not force:
            raise UserError(f"output {out} already exists; choose another {flag} or pass --force.")
        if is_dir:
            check_replaceable(out, flag)
            check_not_locked(out)
        elif ours is None or not ours(out):
            raise UserError(f"{out} is not {ours_what}, and --force replaces only those; move it away or choose "
                            f"another {flag}.")
    check_writable(out, flag)


_KINDS = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def file_kind(mode: int) -> str | None:
    """What a `stat` mode is when it is neither a regular file nor a folder (a FIFO, a device, a socket), else
    None."""
    return next((name for test, name in _KINDS if test(mode)), None)


def umask() -> int:
    """The process's file-mode creation mask."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def remove_path(path: Path) -> None:
    """Remove a folder tree or a file (or nothing, when absent); a folder without write permission inside the tree
    (a copy of a read-only dataset) is made writable first, so what digail made it can always remove."""
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, onerror=_retry_writable)
    elif path.exists() or path.is_symlink():
        path.unlink()


def _retry_writable(func: Callable[..., Any], name: str, exc_info: Any) -> None:
    """`shutil.rmtree`'s error handler: give the folder holding `name` (and `name`, when a folder) the owner's
    write and search permission, then try once more; a second failure is raised."""
    if not isinstance(exc_info[1], PermissionError):
        raise exc_info[1]
    for folder in {os.path.dirname(name), name}:
        with contextlib.suppress(OSError):
            if os.path.isdir(folder) and not os.path.islink(folder):
                os.chmod(folder, os.stat(folder).st_mode | stat.S_IRWXU)
    func(name)


def make_writable(tree: Path) -> None:
    """Give the owner write permission on every file and folder of the copied tree `tree` (links left alone), so
    a copy of a read-only source can be annotated and removed."""
    for root, dirs, files in os.walk(tree):
        for name in [*dirs, *files]:
            path = os.path.join(root, name)
            if not os.path.islink(path):
                os.chmod(path, os.stat(path).st_mode | (stat.S_IRWXU if name in dirs else stat.S_IWUSR))
    os.chmod(tree, os.stat(tree).st_mode | stat.S_IRWXU)


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
            _discard(tmp)
        raise
    if (final.exists() or final.is_symlink()) and not force:  # made by another command meanwhile
        _discard(tmp)
        raise UserError(f"output {final} appeared while this command ran; choose another --out or pass --force.")
    with contextlib.ExitStack() as held:
        if final.is_dir() and not final.is_symlink():
            try:
                held.enter_context(run_dir_lock(final))  # a folder another command is writing is never swapped away
            except BaseException:
                _discard(tmp)
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
                _discard(tmp)
                if old is not None:
                    _discard(old)
                raise
            if old is not None:
                try:
                    remove_path(old)
                except OSError as exc:  # e.g. an immutable file (chattr +i) in the replaced folder
                    reason = (exc.strerror or type(exc).__name__).lower()
                    raise OldOutputLeft(final, old, f"{reason}: {exc.filename}") from None


def _discard(tmp: Path) -> None:
    """Remove a temporary folder of `atomic_dir` on the way out of an error, which is reported instead of any
    failure to remove it."""
    with contextlib.suppress(OSError):
        remove_path(tmp)


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
