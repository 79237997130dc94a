"""Vector envs for training rollouts: synchronous, subprocess (every core) and envpool (C++ threads) backends.

All three share one interface and one semantics, which `digail.algos.rollout.collect_rollout` relies on:

- `reset(seeds)` resets env i with `seeds[i]` and returns float32 observations (N, obs_dim) and the infos;
- `step(actions)` returns the next observations, rewards (float32), terminated and truncated flags, the per-env
  infos and `final`, a dict from the index of every env that ended in this step to its `(final_obs, final_info)`;
  an env that ends is reset in the same step (same-step autoreset, unseeded: its RNG continues), so the returned
  observation of an ended env is its new episode's first;
- time limits come back as `truncated` (the final observation is kept for bootstrapping), never as `terminated`.

The subprocess backend gives the same numbers as the synchronous one for the same seeds (each env's RNG lives in
its own env); envpool's MuJoCo envs follow the same equations but draw their reset noise from their own RNG, so
episodes start elsewhere (see `EnvpoolVecEnv`). Evaluation, demonstrations and experts always use Gymnasium's env.
"""

from __future__ import annotations

import atexit
import contextlib
import importlib.util
import multiprocessing as mp
import os
import signal
import traceback
import weakref
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from typing import Any, Literal, Protocol

import gymnasium as gym
import numpy as np

from digail.envs.registry import env_spec, make_env
from digail.errors import UserError
from digail.user_envs import recorded_spec, register_recorded_env

__all__ = ["Backend", "EnvpoolVecEnv", "SubprocVecEnv", "VecEnv", "VectorEnv", "make_vec_env", "resolve_backend"]

Backend = Literal["auto", "sync", "subproc", "envpool"]
"""auto: the registry's choice for the env (envpool where it covers the env and is installed, else subproc for
MuJoCo-sized envs on a multi-core machine, sync for the tiny grid and circle worlds); sync: one process;
subproc: worker processes; envpool: envpool's C++ batched MuJoCo envs"""

Infos = list[dict[str, Any]]
Final = dict[int, tuple[np.ndarray, dict[str, Any]]]
StepResult = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Infos, Final]


class VectorEnv(Protocol):
    """What `collect_rollout` and the trainers use of a vector env (see the module docstring for the semantics)."""

    num_envs: int
    single_action_space: gym.Space

    @property
    def probe(self) -> gym.Env:
        """an env of the same id in this process for its spaces and action rules (never stepped)"""
        ...

    def reset(self, seeds: Sequence[int | None]) -> tuple[np.ndarray, Infos]: ...

    def step(self, actions: np.ndarray) -> StepResult: ...

    def close(self) -> None: ...


def cpu_count() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


# --------------------------------------------------------------------------------------------------- sync
class VecEnv:
    """N environments stepped in turn in this process; an env that ends is reset in the same step.

    Gymnasium's own vector envs aggregate info dicts at every step, which costs more than the small envs' `step`;
    this one keeps per-step Python work to the envs themselves.
    """

    def __init__(self, env_fns: Sequence[Callable[[], gym.Env]]) -> None:
        self.envs = [fn() for fn in env_fns]
        self.num_envs = len(self.envs)
        self.single_action_space = self.envs[0].action_space

    @staticmethod
    def of(env_id: str, num_envs: int, **kwargs: Any) -> VecEnv:
        return VecEnv([lambda: make_env(env_id, **kwargs) for _ in range(num_envs)])

    @property
    def probe(self) -> gym.Env:
        return self.envs[0]

    def reset(self, seeds: Sequence[int | None]) -> tuple[np.ndarray, Infos]:
        results = [env.reset(seed=s) for env, s in zip(self.envs, seeds, strict=True)]
        return np.stack([np.asarray(o, dtype=np.float32) for o, _ in results]), [i for _, i in results]

    def step(self, actions: np.ndarray) -> StepResult:
        n = self.num_envs
        obs_list: list[Any] = [None] * n
        rews = np.zeros(n, dtype=np.float32)
        terms = np.zeros(n, dtype=bool)
        truncs = np.zeros(n, dtype=bool)
        infos: Infos = [{}] * n
        final: Final = {}
        for i, env in enumerate(self.envs):
            o, r, te, tr, info = env.step(actions[i])
            rews[i], terms[i], truncs[i] = r, te, tr
            if te or tr:
                final[i] = (np.asarray(o, dtype=np.float32), info)
                o, info = env.reset()
            obs_list[i], infos[i] = o, info
        return np.stack(obs_list).astype(np.float32, copy=False), rews, terms, truncs, infos, final

    def close(self) -> None:
        for env in self.envs:
            env.close()


# ------------------------------------------------------------------------------------------------ subproc
class _Shared:
    """The step buffers every worker writes its slice of: float32 observations and final observations, actions,
    rewards and flags, as NumPy views of shared memory (no pickling of arrays on the pipes)."""

    def __init__(self, ctx: Any, n: int, obs_dim: int, act_shape: tuple[int, ...], act_dtype: np.dtype) -> None:
        self.spec = (n, obs_dim, act_shape, np.dtype(act_dtype).str)
        act_bytes = int(np.prod((n, *act_shape))) * np.dtype(act_dtype).itemsize
        self.raw = {"obs": ctx.RawArray("b", 4 * n * obs_dim), "final": ctx.RawArray("b", 4 * n * obs_dim),
                    "acts": ctx.RawArray("b", max(act_bytes, 1)), "rews": ctx.RawArray("b", 4 * n),
                    "terms": ctx.RawArray("b", n), "truncs": ctx.RawArray("b", n)}
        self.views()

    def views(self) -> None:
        n, obs_dim, act_shape, act_dtype = self.spec
        self.obs = np.frombuffer(self.raw["obs"], np.float32).reshape(n, obs_dim)
        self.final = np.frombuffer(self.raw["final"], np.float32).reshape(n, obs_dim)
        self.acts = np.frombuffer(self.raw["acts"], np.dtype(act_dtype),
                                  count=int(np.prod((n, *act_shape)))).reshape(n, *act_shape)
        self.rews = np.frombuffer(self.raw["rews"], np.float32)
        self.terms = np.frombuffer(self.raw["terms"], np.bool_)
        self.truncs = np.frombuffer(self.raw["truncs"], np.bool_)

    def __getstate__(self) -> dict[str, Any]:
        return {"spec": self.spec, "raw": self.raw}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.spec, self.raw = state["spec"], state["raw"]
        self.views()


def _worker(conn: Connection, shared: _Shared, env_id: str, kwargs: dict[str, Any], lo: int, hi: int,
            send_infos: bool, spec: str | None = None) -> None:
    """Steps envs lo..hi-1; commands come on `conn`, arrays go through `shared`. Exits when the parent goes."""
    # Ctrl-C reaches the whole process group: the trainer handles it (checkpoint, cleanup) and then closes the
    # workers; a worker that died of it first would turn the interrupt into a "worker died" error
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    envs: list[gym.Env] = []
    try:
        register_recorded_env(spec, trusted=True)  # the parent's registration (of a module named there) did not travel
        envs = [make_env(env_id, **kwargs) for _ in range(lo, hi)]
        conn.send(("ok", None))
        while True:
            cmd, arg = conn.recv()
            if cmd == "step":
                infos: Infos = []
                final_infos: dict[int, dict[str, Any]] = {}
                for k, env in enumerate(envs):
                    i = lo + k
                    o, r, te, tr, info = env.step(shared.acts[i])
                    shared.rews[i], shared.terms[i], shared.truncs[i] = r, te, tr
                    if te or tr:
                        shared.final[i] = o
                        final_infos[i] = info
                        o, info = env.reset()
                    shared.obs[i] = o
                    if send_infos:
                        infos.append(info)
                conn.send(("ok", (infos, final_infos)))
            elif cmd == "reset":
                infos = []
                for k, env in enumerate(envs):
                    o, info = env.reset(seed=arg[k])
                    shared.obs[lo + k] = o
                    infos.append(info)
                conn.send(("ok", infos))
            elif cmd == "close":
                break
    except (EOFError, BrokenPipeError):  # the parent is gone
        pass
    except Exception as exc:  # noqa: BLE001 - reported to the parent, which raises it
        with contextlib.suppress(BrokenPipeError, OSError):
            conn.send(("error", f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"))
    finally:
        for env in envs:
            env.close()
        conn.close()


def _shutdown(procs: list[Any], conns: list[Connection]) -> None:
    """Ask the workers to stop, then make sure they have (close, garbage collection and interpreter exit)."""
    for conn in conns:
        with contextlib.suppress(BrokenPipeError, OSError):
            conn.send(("close", None))
    for p in procs:
        p.join(timeout=2)
        if p.is_alive():
            p.terminate()
            p.join(timeout=1)
    for conn in conns:
        conn.close()


class SubprocVecEnv:
    """`num_envs` copies of a Gymnasium env stepped by worker processes, several envs each.

    Workers (one per core by default, never more than envs) own contiguous blocks of envs; a step writes the
    actions into shared memory, wakes every worker with one pipe message, and reads observations, rewards and
    flags back from shared memory - only info dicts travel pickled (the final ones always, the others when
    `infos` is set). Same seeds, same numbers as `VecEnv`. Workers start from a forkserver (safe with torch
    loaded and its threads running), die with this process, and stop on `close()`, garbage collection or exit;
    a worker that dies or raises stops the next `step` with an error naming it.

    `step_async` / `step_wait` split a step so that the caller can work while the workers step.
    """

    def __init__(self, env_id: str, num_envs: int, *, workers: int | None = None, infos: bool = True,
                 **kwargs: Any) -> None:
        self.env_id, self.num_envs = env_id, num_envs
        self._probe = make_env(env_id, **kwargs)  # also surfaces a bad id here, as a UserError
        self.single_action_space = self._probe.action_space
        obs_shape = self._probe.observation_space.shape or ()
        act_space = self.single_action_space
        act_shape = tuple(act_space.shape or ())
        act_dtype = np.dtype(np.int64) if isinstance(act_space, gym.spaces.Discrete) else np.dtype(np.float32)
        self._send_infos = infos
        n_workers = max(1, min(workers or cpu_count(), num_envs))
        bounds = np.linspace(0, num_envs, n_workers + 1).round().astype(int)
        self._slices = [(int(bounds[w]), int(bounds[w + 1])) for w in range(n_workers)]
        ctx: Any = mp.get_context("forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn")
        if ctx.get_start_method() == "forkserver":
            # the server imports digail once (the first time it starts); each worker is then a cheap fork
            ctx.set_forkserver_preload(["digail.envs.vector"])
        self._shared = _Shared(ctx, num_envs, int(np.prod(obs_shape)), act_shape, act_dtype)
        self._procs: list[Any] = []
        self._conns: list[Connection] = []
        spec = recorded_spec(env_id)
        for lo, hi in self._slices:
            parent, child = ctx.Pipe()
            p = ctx.Process(target=_worker, args=(child, self._shared, env_id, kwargs, lo, hi, infos, spec),
                            daemon=True, name=f"digail-env-{lo}-{hi - 1}")
            p.start()
            child.close()
            self._procs.append(p)
            self._conns.append(parent)
        self._finalizer = weakref.finalize(self, _shutdown, self._procs, self._conns)
        atexit.register(self._finalizer)
        self._waiting = False
        for w in range(len(self._procs)):
            self._recv(w)  # the envs were made (or the worker's error is raised here)

    @property
    def processes(self) -> tuple[Any, ...]:
        """The worker processes, one per slice of envs (`multiprocessing` processes: pid, is_alive, ...)."""
        return tuple(self._procs)

    @property
    def probe(self) -> gym.Env:
        return self._probe

    def _recv(self, w: int) -> Any:
        try:
            status, payload = self._conns[w].recv()
        except (EOFError, ConnectionResetError, OSError) as exc:
            code = self._procs[w].exitcode
            self.close()
            lo, hi = self._slices[w]
            raise RuntimeError(f"environment worker {w} (envs {lo}-{hi - 1} of {self.env_id}) died "
                               f"(exit code {code}); the vector env is closed.") from exc
        if status == "error":
            self.close()
            lo, hi = self._slices[w]
            raise RuntimeError(f"environment worker {w} (envs {lo}-{hi - 1} of {self.env_id}) failed: {payload}")
        return payload

    def _send(self, w: int, msg: tuple[str, Any]) -> None:
        try:
            self._conns[w].send(msg)
        except (BrokenPipeError, OSError) as exc:
            self._recv(w)  # raises the worker's error or death
            raise RuntimeError(f"environment worker {w} is unreachable") from exc

    def reset(self, seeds: Sequence[int | None]) -> tuple[np.ndarray, Infos]:
        seeds = list(seeds)
        if len(seeds) != self.num_envs:
            raise ValueError(f"expected {self.num_envs} seeds, got {len(seeds)}")
        for w, (lo, hi) in enumerate(self._slices):
            self._send(w, ("reset", seeds[lo:hi]))
        infos: Infos = []
        for w in range(len(self._procs)):
            infos.extend(self._recv(w))
        return self._shared.obs.copy(), infos

    def step_async(self, actions: np.ndarray) -> None:
        self._shared.acts[...] = actions
        for w in range(len(self._procs)):
            self._send(w, ("step", None))
        self._waiting = True

    def step_wait(self) -> StepResult:
        self._waiting = False
        infos: Infos = []
        final: Final = {}
        sh = self._shared
        for w in range(len(self._procs)):
            w_infos, final_infos = self._recv(w)
            infos.extend(w_infos)
            for i, info in final_infos.items():
                final[i] = (sh.final[i].copy(), info)
        if not self._send_infos:
            infos = [{} for _ in range(self.num_envs)]
        return sh.obs.copy(), sh.rews.copy(), sh.terms.copy(), sh.truncs.copy(), infos, final

    def step(self, actions: np.ndarray) -> StepResult:
        self.step_async(actions)
        return self.step_wait()

    def close(self) -> None:
        if self._finalizer.alive:
            self._finalizer()
            atexit.unregister(self._finalizer)
        self._probe.close()


# ------------------------------------------------------------------------------------------------ envpool
def envpool_available() -> bool:
    """Whether the envpool package is installed (it is an optional extra)."""
    return importlib.util.find_spec("envpool") is not None


class EnvpoolVecEnv:
    """envpool's C++ batched MuJoCo env (threads outside the GIL) behind the same interface as `VecEnv`.

    Dynamics, rewards, termination and time limits follow Gymnasium's v5 envs: from the same state, the same
    actions give observations equal to ~1e-14 and rewards equal in float32 (tests/test_vector.py checks it with
    the reset noise off). The time limit is counted here, so that a failure on the limit's step is terminated
    and truncated, as Gymnasium's TimeLimit says (envpool alone would call it truncated only).

    What cannot match is the reset noise: envpool draws it from its own RNG, so with the same seed an episode
    starts from a different (equally distributed) state - training on it is training on the same MDP, and
    imitation, which compares state distributions, does not see the difference. The shipped Hopper and Walker2d
    experts score within 5% of their Gymnasium return on it (tested).

    `reset(seeds)` rebuilds the pool with `env_seed = seeds`, so a seeded reset (a fresh run, a resume) restarts
    every env's RNG exactly as the same seeds do on a second run. Ended envs are reset in the same step
    (envpool's own autoreset is one step late, and never fires here because every ended env is reset at once).
    """

    def __init__(self, env_id: str, num_envs: int, *, threads: int | None = None, infos: bool = True,
                 **kwargs: Any) -> None:
        if not envpool_available():
            raise UserError("the envpool backend needs the envpool package; `pip install envpool` or pick "
                            "`--train.backend subproc`.")
        spec = env_spec(env_id)
        if spec is None or not spec.envpool:
            raise UserError(f"envpool has no {env_id!r}; envpool covers "
                            f"{', '.join(s.env_id for s in _envpool_specs())}. Pick `--train.backend subproc`.")
        self.env_id, self.num_envs = env_id, num_envs
        self._threads = max(1, min(threads or cpu_count(), num_envs))
        self._probe = make_env(env_id, **kwargs)
        # The time limit is kept here, as Gymnasium's TimeLimit keeps it: envpool reports a failure on the limit's
        # step as truncated only, where Gymnasium says terminated and truncated (a fall there is not bootstrapped).
        spec_limit = self._probe.spec.max_episode_steps if self._probe.spec is not None else None
        self._limit = kwargs.pop("max_episode_steps", spec_limit)
        self._kwargs = kwargs  # envpool's names for Gymnasium's options (e.g. reset_noise_scale)
        if self._limit is not None:
            self._kwargs["max_episode_steps"] = self._limit + 1
        self._elapsed = np.zeros(num_envs, dtype=np.int64)
        self.single_action_space = self._probe.action_space
        self._send_infos = infos
        self._pool: Any = None
        self._make([None] * num_envs)

    def _make(self, seeds: Sequence[int | None]) -> None:
        import envpool

        if self._pool is not None:
            self._pool.close()
        rng = np.random.default_rng()
        env_seed = [int(s) if s is not None else int(rng.integers(2**31 - 1)) for s in seeds]
        self._pool = envpool.make_gymnasium(self.env_id, num_envs=self.num_envs, batch_size=self.num_envs,
                                            num_threads=self._threads, env_seed=env_seed, **self._kwargs)
        self._all = np.arange(self.num_envs, dtype=np.int32)

    @property
    def probe(self) -> gym.Env:
        return self._probe

    def _infos(self, info: dict[str, Any], idx: Sequence[int] | np.ndarray) -> Infos:
        keys = [k for k in info if k not in ("env_id", "players", "elapsed_step")]
        return [{k: info[k][j].item() for k in keys} for j in range(len(idx))]

    def reset(self, seeds: Sequence[int | None]) -> tuple[np.ndarray, Infos]:
        seeds = list(seeds)
        if len(seeds) != self.num_envs:
            raise ValueError(f"expected {self.num_envs} seeds, got {len(seeds)}")
        self._make(seeds)
        self._elapsed[:] = 0
        obs, info = self._pool.reset()
        return np.asarray(obs, dtype=np.float32), self._infos(info, self._all)

    def step(self, actions: np.ndarray) -> StepResult:
        obs, rews, terms, truncs, info = self._pool.step(np.asarray(actions, dtype=np.float64), env_id=self._all)
        obs = np.asarray(obs, dtype=np.float32)
        self._elapsed += 1
        terms = np.asarray(terms, dtype=bool)
        truncs = self._elapsed >= self._limit if self._limit is not None else np.asarray(truncs, dtype=bool)
        infos: Infos = self._infos(info, self._all) if self._send_infos else [{} for _ in range(self.num_envs)]
        final: Final = {}
        done = np.flatnonzero(terms | truncs)
        if len(done):
            done_infos = infos if self._send_infos else self._infos(info, self._all)
            for i in done:
                final[int(i)] = (obs[i].copy(), done_infos[i])
            self._elapsed[done] = 0
            new_obs, new_info = self._pool.reset(env_id=done.astype(np.int32))
            obs[done] = new_obs
            if self._send_infos:
                for j, d in enumerate(self._infos(new_info, done)):
                    infos[int(done[j])] = d
        return obs, np.asarray(rews, dtype=np.float32), terms, truncs, infos, final

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool = None
        self._probe.close()


def _envpool_specs() -> list[Any]:
    from digail.envs.registry import ENV_SPECS

    return [s for s in ENV_SPECS.values() if s.envpool]


# ------------------------------------------------------------------------------------------------ choice
def resolve_backend(env_id: str, backend: Backend = "auto") -> Literal["sync", "subproc", "envpool"]:
    """The backend `backend` means for `env_id`: `auto` follows the env's registry entry (measured per env:
    benchmarks/throughput.py), else envpool where it covers the env and is installed, else subproc on a
    multi-core machine; an explicit choice is checked."""
    spec = env_spec(env_id)
    if backend == "auto":
        if spec is not None and spec.envpool and envpool_available():
            return "envpool"
        if spec is not None and spec.auto_backend == "sync":
            return "sync"
        return "subproc" if cpu_count() > 1 else "sync"
    if backend == "envpool":
        if not envpool_available():
            raise UserError("`--train.backend envpool` needs the envpool package; `pip install envpool` or pick "
                            "`--train.backend subproc`.")
        if spec is None or not spec.envpool:
            raise UserError(f"envpool has no {env_id!r}; it covers "
                            f"{', '.join(s.env_id for s in _envpool_specs())}. Pick `--train.backend subproc`.")
    if backend not in ("sync", "subproc", "envpool"):
        raise UserError(f"unknown backend {backend!r}; choose auto, sync, subproc or envpool.")
    return backend


def make_vec_env(env_id: str, num_envs: int, backend: Backend = "auto", *, workers: int = 0,
                 infos: bool = True) -> VectorEnv:
    """`num_envs` copies of `env_id` on `backend` (`resolve_backend`); `workers` processes or threads for the
    parallel backends (0: one per core); `infos=False` skips the per-step info dicts (final infos stay)."""
    chosen = resolve_backend(env_id, backend)
    if chosen == "sync":
        spec = env_spec(env_id)
        if spec is not None and spec.batched is not None:  # the env's own array implementation, same numbers
            return spec.batched(env_id, num_envs)  # type: ignore[no-any-return]
        return VecEnv.of(env_id, num_envs)
    if chosen == "subproc":
        return SubprocVecEnv(env_id, num_envs, workers=workers or None, infos=infos)
    return EnvpoolVecEnv(env_id, num_envs, threads=workers or None, infos=infos)
