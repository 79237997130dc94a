"""The off-policy learner's replay buffer: every transition one float32 row of a preallocated table, so that a
sampled batch is a single gather whose column slices are the update's inputs; checkpointed as named tensors."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from digail.errors import UserError

FIELDS = ("obs", "codes", "acts", "next_obs", "next_codes", "terminated", "bonus", "rews")
"""what every stored transition holds (see `ReplayBuffer`), in the checkpoint's names"""


class ReplayBuffer:
    """A ring of the last `capacity` transitions (s_t, c_t, a_t, s_{t+1}, c_{t+1}, terminated, bonus, env reward).

    `obs` / `next_obs` are normalised observations (the normaliser is fixed during training), `acts` the executed
    actions (what D and the critics see), `next_obs` the final observation where an episode ended, `next_codes`
    the code the macro-policy chose for s_{t+1} during the rollout (the one the bootstrap target uses),
    `terminated` true only for an end by termination (a time limit is bootstrapped), `bonus` the directed-info
    bonus log q(c_{t+1} | s_{t+1}, c_t) of the transition (q is frozen, so it is stored once) and `rews` the env's
    reward (logged, and the reward of runs on the env's own reward). D's reward is not stored: it is relabelled
    with the current D on every sampled batch.

    Storage: one row per transition, [s, one-hot c, a, s', one-hot c', terminated, bonus, r] (float32), so that
    [s, c, a] (the critics' input), [s, c] and [s', c'] are column slices of a gathered batch; the codes are also
    kept as integers (`codes`, `next_codes`). The attributes `obs`, `acts`, ... are NumPy views of the table's
    columns. On CUDA a copy of the table lives on the device and batches are gathered there.
    """

    def __init__(self, capacity: int, obs_dim: int, act_dim: int, codes: int,
                 device: torch.device | str = "cpu") -> None:
        self.capacity, self.obs_dim, self.act_dim, self.num_codes = capacity, obs_dim, act_dim, codes
        widths = {"obs": obs_dim, "code_1h": codes, "acts": act_dim, "next_obs": obs_dim, "next_code_1h": codes,
                  "terminated": 1, "bonus": 1, "rews": 1}
        ends = np.cumsum(list(widths.values())).tolist()
        self.cols = {name: (end - w, end) for (name, w), end in zip(widths.items(), ends, strict=True)}
        """each part's columns [start, end) in a row"""
        self.width = ends[-1]
        check_buffer_memory(capacity, self.width)
        self.table = np.zeros((capacity, self.width), np.float32)
        self.obs, self.acts, self.next_obs = (self.table[:, slice(*self.cols[n])]
                                              for n in ("obs", "acts", "next_obs"))
        self.terminated_f, self.bonus, self.rews = (self.table[:, self.cols[n][0]]
                                                    for n in ("terminated", "bonus", "rews"))
        self.codes = np.zeros(capacity, np.int64)
        self.next_codes = np.zeros(capacity, np.int64)
        self.device = torch.device(device)
        self.rows = (torch.from_numpy(self.table) if self.device.type == "cpu"
                     else torch.zeros(capacity, self.width, device=self.device))
        """the table as a tensor on the device (on the CPU: the same memory)"""
        self._eye = np.eye(codes, dtype=np.float32)
        self.pos = 0
        """where the next transition goes"""
        self.size = 0
        """transitions held"""

    @property
    def terminated(self) -> np.ndarray:
        """(capacity,) bool: the episode ended by termination at s'"""
        return self.terminated_f > 0.5

    def add(self, obs: np.ndarray, codes: np.ndarray, acts: np.ndarray, next_obs: np.ndarray,
            next_codes: np.ndarray, terminated: np.ndarray, bonus: np.ndarray, rews: np.ndarray) -> None:
        """Store a batch of N transitions (one per env), each argument an array with N rows."""
        n = len(obs)
        idx: Any = (slice(self.pos, self.pos + n) if self.pos + n <= self.capacity
                    else (self.pos + np.arange(n)) % self.capacity)
        t, c = self.table, self.cols
        t[idx, slice(*c["obs"])] = obs
        t[idx, slice(*c["code_1h"])] = self._eye[codes]
        t[idx, slice(*c["acts"])] = np.asarray(acts).reshape(n, -1)
        t[idx, slice(*c["next_obs"])] = next_obs
        t[idx, slice(*c["next_code_1h"])] = self._eye[next_codes]
        t[idx, c["terminated"][0]] = terminated
        t[idx, c["bonus"][0]] = bonus
        t[idx, c["rews"][0]] = rews
        self.codes[idx] = codes
        self.next_codes[idx] = next_codes
        if self.device.type != "cpu":  # the device's copy of the rows just written
            rows = torch.from_numpy(t[idx]).to(self.device)
            if isinstance(idx, slice):
                self.rows[idx] = rows
            else:
                self.rows[torch.as_tensor(idx, device=self.device)] = rows
        self.pos = int((self.pos + n) % self.capacity)
        self.size = min(self.size + n, self.capacity)

    def sample_indices(self, n: int, gen: torch.Generator) -> torch.Tensor:
        """`n` indices drawn uniformly with replacement from the held transitions (from the torch generator, so
        that a resumed run draws the same)."""
        return torch.randint(self.size, (n,), generator=gen)

    def gather(self, idx: torch.Tensor | np.ndarray) -> torch.Tensor:
        """The rows at `idx` (n, width) on the device, in one gather."""
        return self.rows.index_select(0, torch.as_tensor(idx).to(self.device))

    def split(self, rows: torch.Tensor) -> dict[str, torch.Tensor]:
        """Named column views of gathered rows: obs, code_1h, acts, next_obs, next_code_1h (n, .), terminated (n,)
        bool, bonus, rews (n,)."""
        c = self.cols
        out = {name: rows[:, a:b] for name, (a, b) in c.items() if name not in ("terminated", "bonus", "rews")}
        out["terminated"] = rows[:, c["terminated"][0]] > 0.5
        out["bonus"] = rows[:, c["bonus"][0]]
        out["rews"] = rows[:, c["rews"][0]]
        return out

    def get(self, idx: torch.Tensor | np.ndarray) -> dict[str, torch.Tensor]:
        """The transitions at `idx` as named tensors on the buffer's device (`split` of `gather`)."""
        return self.split(self.gather(idx))

    def state_dict(self) -> dict[str, Any]:
        """The held transitions as tensors (weights_only-loadable), in storage order, with the write position."""
        n = self.size
        arrays = {"obs": self.obs[:n], "codes": self.codes[:n], "acts": self.acts[:n], "next_obs": self.next_obs[:n],
                  "next_codes": self.next_codes[:n], "terminated": self.terminated[:n], "bonus": self.bonus[:n],
                  "rews": self.rews[:n]}
        return {"pos": self.pos, "size": n, "capacity": self.capacity,
                **{name: torch.from_numpy(np.ascontiguousarray(arrays[name]).copy()) for name in FIELDS}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        damaged = "the checkpoint is damaged; restore it or start the training again"
        n, pos = int(state["size"]), int(state["pos"])
        if int(state["capacity"]) != self.capacity:
            raise UserError(f"the checkpoint's replay buffer holds {state['capacity']} transitions, this run's "
                            f"{self.capacity}; resume with the run's own settings.")
        # a ring fills from 0: until it is full the write position is its size, afterwards anywhere inside it
        fits = 0 <= n <= self.capacity and (0 <= pos < self.capacity if n == self.capacity else pos == n)
        if not fits:
            raise UserError(f"the checkpoint's replay buffer records {n} transitions and write position {pos}, which "
                            f"do not fit its capacity of {self.capacity}; {damaged}.")
        arrays = {name: state[name].numpy() for name in FIELDS}
        shapes = {"obs": (self.obs_dim,), "next_obs": (self.obs_dim,), "acts": (self.act_dim,)}
        for name, arr in arrays.items():
            held = len(arr) if arr.ndim else 0
            if arr.ndim < 1 or held != n:
                raise UserError(f"the checkpoint's replay buffer records {n} transitions but holds {held} in "
                                f"'{name}'; {damaged}.")
            if arr.shape[1:] != shapes.get(name, ()):
                raise UserError("the checkpoint's replay buffer does not fit this model's observations or actions; "
                                "resume with the run's own settings.")
            if np.issubdtype(arr.dtype, np.floating) and not np.isfinite(arr).all():
                raise UserError(f"the checkpoint's replay buffer holds NaN or inf values in '{name}'; {damaged}.")
        if n and (max(arrays["codes"].max(), arrays["next_codes"].max()) >= self.num_codes
                  or min(arrays["codes"].min(), arrays["next_codes"].min()) < 0):
            raise UserError("the checkpoint's replay buffer holds codes this model does not have; resume with the "
                            "run's own settings.")
        self.pos, self.size = 0, 0
        if n:
            self.add(**arrays)
        self.pos, self.size = pos, n


def check_buffer_memory(capacity: int, width: int) -> None:
    """Refuse, in one sentence, a replay buffer larger than the memory this machine can hand out: a float32 row of
    `width` columns and two int64 codes per transition."""
    from digail.utils import available_memory, human_bytes

    need = int(capacity) * (4 * int(width) + 16)
    free = available_memory()
    if free is not None and need > free:
        raise UserError(f"--train.sac.buffer-size {capacity} needs {human_bytes(need)} for its replay buffer but "
                        f"{human_bytes(free)} of memory is available; lower it (it need not exceed the training's "
                        "environment steps).")
