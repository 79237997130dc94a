"""Connecting a sweep to Ray: a local Ray that stays on this machine and leaves nothing behind, or a cluster.

A local Ray started here listens on the loopback interface only (GCS, raylet, workers, runtime-env agent; no
dashboard unless asked for, and then bound to 127.0.0.1), keeps its session files in a temporary folder of its own
and is watched by a small reaper process: when the driver ends, however it ends (even by SIGKILL), the reaper kills
whatever of this Ray is left and removes the folder. Everything a sweep can check about the cluster (that the
address answers, that a trial's CPUs and GPUs fit on one node, that the dashboard's packages are installed) is
checked before anything is written.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass
from typing import Any

from digail.errors import UserError

LOOPBACK = "127.0.0.1"
CONNECT_TIMEOUT_S = 5.0
"""how long a cluster address may take to accept a connection before the sweep gives up"""

SESSION_ENV = "DIGAIL_RAY_SESSION"
"""environment variable naming a local Ray's folder in every process of that Ray (how the reaper finds them)"""

_REAPER = r"""
import os, shutil, signal, sys, time
folder, driver = sys.argv[1], int(sys.argv[2])
sys.stdin.buffer.read()  # returns when the driver closes its end or dies
marker = f"{os.environ.get('SESSION_ENV_NAME')}={folder}".encode()
def ours():
    pids = []
    for name in os.listdir("/proc"):
        if name.isdigit() and int(name) not in (os.getpid(), driver):
            try:
                with open(f"/proc/{name}/environ", "rb") as f:
                    if marker in f.read().split(b"\0"):
                        pids.append(int(name))
            except OSError:
                pass
    return pids
for _ in range(50):
    pids = ours()
    if not pids:
        break
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
    time.sleep(0.1)
shutil.rmtree(folder, ignore_errors=True)
"""


_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_caught: list[int] = []
"""signals that arrived while a sweep held Ray (newest last)"""
_handlers: list[dict[int, Any]] = []
"""the handlers `_remember_signals` wrapped, one dict per session holding Ray"""


def _remember_signals() -> dict[int, Any]:
    """Wrap SIGINT's and SIGTERM's handlers so that the signal's number is kept: Ray's blocking calls turn
    whatever the handler raised into a bare KeyboardInterrupt, and `reraise_signal` restores it."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    _caught.clear()
    old: dict[int, Any] = {int(s): signal.getsignal(s) for s in _SIGNALS}

    def remember(signum: int, frame: Any) -> None:
        _caught.append(signum)
        handler = old[signum]
        if callable(handler):
            handler(signum, frame)
        elif signum == signal.SIGINT:
            raise KeyboardInterrupt
        else:
            raise SystemExit(128 + signum)

    for s in _SIGNALS:
        signal.signal(s, remember)
    return old


def reraise_signal(exc: KeyboardInterrupt) -> None:
    """Raise again what the original handler of the signal behind `exc` raises (e.g. the CLI's SIGTERM exit), when
    Ray replaced it with a bare KeyboardInterrupt; else re-raise `exc`."""
    handlers = _handlers[-1] if _handlers else {}
    if type(exc) is KeyboardInterrupt and _caught and callable(handlers.get(_caught[-1])):
        handlers[_caught[-1]](_caught[-1], None)
    raise exc


@dataclass
class RaySession:
    """A connection to Ray made by `start_ray`; `stop_ray` ends what it started."""

    started: bool
    """whether this process started the Ray (and so shuts it down)"""
    folder: str | None = None
    """the local Ray's session folder (removed at the end)"""
    reaper: subprocess.Popen[bytes] | None = None
    """the process that cleans up after the driver"""
    client: bool = False
    """whether the driver is a Ray Client (ray://): it is then on no node of the cluster"""
    connected: bool = False
    """whether this process connected to a running cluster (and so disconnects)"""
    signals: bool = False
    """whether SIGINT's and SIGTERM's handlers were wrapped (and so are restored)"""


def _host_port(address: str) -> tuple[str, int] | None:
    """(host, port) of a 'host:port' or 'ray://host:port' address; None for 'auto' and other forms."""
    body = address.split("://", 1)[1] if "://" in address else address
    host, sep, port = body.rpartition(":")
    if not sep or not port.isdigit():
        return None
    return host.strip("[]") or LOOPBACK, int(port)


def check_reachable(address: str, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """Raise a UserError unless something accepts connections at `address` within `timeout` seconds."""
    hp = _host_port(address)
    if hp is None:
        if address != "auto":
            raise UserError(f"--address {address!r} is not a Ray address; write HOST:PORT, ray://HOST:PORT or auto.")
        return
    try:
        with socket.create_connection(hp, timeout=timeout):
            pass
    except OSError as exc:
        raise UserError(f"no Ray cluster answers at {address} ({exc.strerror or type(exc).__name__} within "
                        f"{timeout:g} s); start one with `ray start --head` there or fix --address.") from None


def check_dashboard_installed() -> None:
    import ray._private.utils as ray_utils

    missing = ray_utils.get_dashboard_dependency_error()
    if missing is not None:
        raise UserError(f"--dashboard needs Ray's dashboard packages ({missing}); pip install 'ray[default]' or "
                        "leave --dashboard out.")


def local_gpus() -> int:
    """GPUs torch sees on this machine."""
    import torch

    return torch.cuda.device_count() if torch.cuda.is_available() else 0


def check_fits(nodes: list[dict[str, float]], cpus: float, gpus: float, resources: dict[str, float],
               where: str) -> None:
    """Raise a UserError unless one node of `nodes` (their total resources) can hold a trial."""
    need = {"CPU": cpus, "GPU": gpus, **resources}
    for node in nodes:
        if all(node.get(k, 0.0) >= v for k, v in need.items() if v > 0):
            return
    best = {k: max((n.get(k, 0.0) for n in nodes), default=0.0) for k in need}
    short = [k for k, v in need.items() if v > 0 and best[k] < v]
    if "GPU" in short:
        raise UserError(f"--gpus-per-trial {gpus:g} but {where} has {best['GPU']:g} GPUs per node; run on a "
                        "machine or cluster with GPUs, or leave --gpus-per-trial out.")
    what = ", ".join(f"{need[k]:g} {k}" for k in short)
    have = ", ".join(f"{best[k]:g} {k}" for k in short)
    raise UserError(f"a trial needs {what} but the largest node of {where} has {have}, so no trial could ever start; "
                    "lower --cpus-per-trial (or the spec's resources_per_trial) or use a larger node.")


def loopback_only() -> None:
    """Make a Ray started from this process take 127.0.0.1 as its node address (every server binds it).

    Ray binds its servers to the node address; on Linux it picks the machine's outward address unless clusters are
    switched off, which is Ray's switch for a one-machine Ray. The variable is read when Ray is imported and by the
    processes it starts, so both are set."""
    import ray._private.ray_constants as ray_constants

    os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
    ray_constants.ENABLE_RAY_CLUSTER = False


def _start_reaper(folder: str) -> subprocess.Popen[bytes]:
    env = {**os.environ, "SESSION_ENV_NAME": SESSION_ENV}
    env.pop(SESSION_ENV, None)  # the reaper is not part of the Ray it reaps
    return subprocess.Popen([sys.executable, "-c", _REAPER, folder, str(os.getpid())], stdin=subprocess.PIPE,
                            env=env, start_new_session=True, close_fds=True)


def start_ray(address: str | None = None, num_cpus: int | None = None, dashboard: bool = False, *,
              cpus_per_trial: float = 1.0, gpus_per_trial: float = 0.0,
              resources_per_trial: dict[str, float] | None = None) -> RaySession:
    """Connect to the cluster at `address` (or $RAY_ADDRESS), else start a local Ray sized to this machine.

    Refuses (UserError, nothing started or left running) an address that does not answer, a trial that fits on no
    node, GPUs where there are none and a dashboard without its packages. A Ray already initialised in this
    process (a test's) is used as it is."""
    import ray

    resources = dict(resources_per_trial or {})
    if ray.is_initialized():
        nodes = [n["Resources"] for n in ray.nodes() if n.get("Alive")]
        check_fits(nodes, cpus_per_trial, gpus_per_trial, resources, "the running Ray")
        return RaySession(started=False, client=ray.util.client.ray.is_connected())
    address = address or os.environ.get("RAY_ADDRESS") or None
    if dashboard:
        check_dashboard_installed()
    if address:
        check_reachable(address)
        return _connect(address, cpus_per_trial, gpus_per_trial, resources)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    cpus = num_cpus or cores
    gpus = local_gpus()
    check_fits([{"CPU": float(cpus), "GPU": float(gpus)}], cpus_per_trial, gpus_per_trial, resources,
               "this machine's Ray" if num_cpus is None else f"a local Ray of --num-cpus {num_cpus}")
    loopback_only()
    folder = tempfile.mkdtemp(prefix="digail-ray-")
    os.environ[SESSION_ENV] = folder  # inherited by every process of this Ray: how the reaper knows them
    reaper = _start_reaper(folder)
    session = RaySession(started=True, folder=folder, reaper=reaper)
    old_term = signal.getsignal(signal.SIGTERM) if threading.current_thread() is threading.main_thread() else None
    try:
        ray.init(num_cpus=cpus, num_gpus=gpus, include_dashboard=dashboard, dashboard_host=LOOPBACK,
                 log_to_driver=False, object_store_memory=200 * 1024**2, _temp_dir=folder)
    except BaseException:
        stop_ray(session)
        raise
    finally:
        if old_term is not None:  # Ray replaces SIGTERM's handler with a bare exit; the caller's stays in force
            signal.signal(signal.SIGTERM, old_term)
    _handlers.append(_remember_signals())
    session.signals = True
    return session


def _connect(address: str, cpus: float, gpus: float, resources: dict[str, float]) -> RaySession:
    import ray

    old_term = signal.getsignal(signal.SIGTERM) if threading.current_thread() is threading.main_thread() else None
    try:
        ray.init(address=address, log_to_driver=False)
    except ConnectionError as exc:
        raise UserError(f"no Ray cluster at --address {address} ({_first_line(exc)}); start one with "
                        "`ray start --head` or fix --address.") from None
    except Exception as exc:  # e.g. a port that answers but is no Ray
        raise UserError(f"cannot connect to a Ray cluster at {address} ({_first_line(exc)}); check --address.") \
            from None
    finally:
        if old_term is not None:
            signal.signal(signal.SIGTERM, old_term)
    session = RaySession(started=False, client="://" in address)
    try:
        nodes = [n["Resources"] for n in ray.nodes() if n.get("Alive")]
        check_fits(nodes, cpus, gpus, resources, f"the cluster at {address}")
    except BaseException:
        ray.shutdown()
        raise
    session.connected = True
    _handlers.append(_remember_signals())
    session.signals = True
    return session


def stop_ray(session: RaySession) -> None:
    """Shut down what `start_ray` started (or disconnect), then let the reaper clean up and wait for it."""
    import ray

    if session.signals and _handlers:
        session.signals = False
        for s, handler in _handlers.pop().items():
            signal.signal(s, handler)
    if session.started or session.connected:
        ray.shutdown()
    if session.reaper is not None:
        if session.reaper.stdin is not None:
            session.reaper.stdin.close()  # the reaper's cue
        try:
            session.reaper.wait(timeout=30)
        except subprocess.TimeoutExpired:
            session.reaper.kill()
    if session.folder is not None and os.environ.get(SESSION_ENV) == session.folder:
        del os.environ[SESSION_ENV]


def _first_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text.split(". ", 1)[0].rstrip(".") if text else type(exc).__name__
