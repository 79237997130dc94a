"""Optimal-transport rewards: an agent episode matched against the demonstrations (ROT, Haldar et al. 2022), with
no discriminator to saturate.

For each demonstration, an entropic transport plan (Sinkhorn, log domain) between the episode's steps and the
demonstration's, uniform mass on each side, on the cosine distance (or, with `ot_cost`, the Euclidean) of D's view of
the observations (`--train.imitation.disc-obs`). An agent step's reward is minus `ot_scale` times the cost its mass
pays, averaged over the `ot_top_k` demonstrations the episode is cheapest to move onto. `ot-subtask` adds
`ot_code_penalty` where the agent's code and the code q gave the demonstration step differ, so a step under sub-task
c is matched to the demonstration's steps of sub-task c wherever the marginals allow. `ot_time_weight` adds a cost
for matching steps far apart in episode time (the in-order variant).

Pieces of episodes (a PPO rollout cuts episodes at its ends; an off-policy run restarts its envs at checkpoints)
are matched against the demonstrations' steps over the same stretch of episode time, which is exact for
fixed-length tasks such as Fetch's 50 steps.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from digail.algos.rewards.base import EnvStep, RewardHost, Rollout, Steps
from digail.algos.rewards.views import RewardInputs
from digail.errors import UserError

_NEG = -1e9
"""log of a mass that is not there (finite, so that masked rows and columns never give inf - inf)"""


def sinkhorn_plan(cost: torch.Tensor, a_mask: torch.Tensor, b_mask: torch.Tensor, epsilon: float,
                  iterations: int) -> torch.Tensor:
    """The entropic optimal-transport plan (..., n, m) between uniform masses on the valid rows (`a_mask`, (..., n)
    bool) and valid columns (`b_mask`, (..., m)) for `cost` (..., n, m): Sinkhorn's iterations on the log
    potentials, so small `epsilon` neither underflows nor overflows. Its column sums are exactly b's (the last
    iteration fits them), its row sums a's up to the iterations' convergence; masked entries are 0."""
    a_mask, b_mask = a_mask.bool(), b_mask.bool()
    n_a = a_mask.sum(-1, keepdim=True).clamp_min(1).to(cost)
    n_b = b_mask.sum(-1, keepdim=True).clamp_min(1).to(cost)
    log_a = torch.where(a_mask, -torch.log(n_a), torch.full_like(n_a, _NEG))
    log_b = torch.where(b_mask, -torch.log(n_b), torch.full_like(n_b, _NEG))
    both = a_mask.unsqueeze(-1) & b_mask.unsqueeze(-2)
    log_k = torch.where(both, -cost / epsilon, torch.full_like(cost, _NEG))
    u = torch.zeros_like(log_a)
    v = torch.zeros_like(log_b)
    for _ in range(iterations):
        u = log_a - torch.logsumexp(log_k + v.unsqueeze(-2), dim=-1)
        v = log_b - torch.logsumexp(log_k + u.unsqueeze(-1), dim=-2)
    return torch.exp(log_k + u.unsqueeze(-1) + v.unsqueeze(-2)) * both


def cosine_cost(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """1 - cos(x_i, y_j) for every pair: x (..., n, F), y (..., m, F) -> (..., n, m), in [0, 2]."""
    xn = torch.nn.functional.normalize(x, dim=-1, eps=1e-8)
    yn = torch.nn.functional.normalize(y, dim=-1, eps=1e-8)
    return 1.0 - xn @ yn.transpose(-1, -2)


def euclidean_cost(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """The root-mean-square difference per feature of every pair, |x_i - y_j| / sqrt(F): x (..., n, F), y (..., m,
    F) -> (..., n, m). On standardised features it is in units of the demonstrations' spread, and unlike the cosine
    it grows with how far a step is from a demonstration's, not with the angle between them."""
    return torch.cdist(x, y).div(math.sqrt(x.shape[-1]))


COSTS = {"cosine": cosine_cost, "euclidean": euclidean_cost}
"""the names `--train.imitation.ot-cost` takes"""


def ot_step_rewards(agent: torch.Tensor, agent_mask: torch.Tensor, demos: torch.Tensor, demo_mask: torch.Tensor, *,
                    epsilon: float, iterations: int, top_k: int, scale: float, metric: str = "cosine",
                    agent_codes: torch.Tensor | None = None, demo_codes: torch.Tensor | None = None,
                    code_penalty: float = 0.0, agent_times: torch.Tensor | None = None,
                    time_weight: float = 0.0, demo_lengths: torch.Tensor | None = None
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """The transport reward of S agent pieces against M demonstrations.

    Args:
        agent: (S, L, F) the pieces' features, padded; `agent_mask` (S, L) bool marks real steps.
        demos: (M, Ld, F) the demonstrations' features, padded; `demo_mask` (S, M, Ld) bool marks the steps each
            piece is matched against (a whole demonstration, or the stretch of episode time a piece covers).
        agent_codes: (S, L) int codes of the agent's steps; with `code_penalty` > 0 a pair whose codes differ
            costs that much more.
        demo_codes: (M, Ld) int codes of the demonstrations' steps.
        metric: the distance between two steps' features, `cosine` (ROT's) or `euclidean` (`COSTS`).
        agent_times: (S, L) each step's time in its episode; with `time_weight` > 0 a pair costs that times
            |t_agent - t_demo| / (the demonstration's length, `demo_lengths` (M,), default Ld) more.

    Returns:
        (S, L) rewards (0 on padding) and (S, M) each piece's total transport cost to each demonstration.
    """
    cost = COSTS[metric](agent.unsqueeze(1), demos.unsqueeze(0))  # (S, M, L, Ld)
    if code_penalty > 0 and agent_codes is not None and demo_codes is not None:
        cost = cost + code_penalty * (agent_codes[:, None, :, None] != demo_codes[None, :, None, :]).to(cost)
    if time_weight > 0 and agent_times is not None:
        lengths = (torch.full(demos.shape[:1], demos.shape[1], device=cost.device) if demo_lengths is None
                   else demo_lengths)
        steps = torch.arange(demos.shape[1], device=cost.device, dtype=cost.dtype)
        gap = (agent_times[:, None, :, None].to(cost) - steps[None, None, None, :]).abs()
        cost = cost + time_weight * gap / lengths.clamp_min(1).to(cost)[None, :, None, None]
    a_mask = agent_mask[:, None, :].expand(-1, demos.shape[0], -1)
    plan = sinkhorn_plan(cost, a_mask, demo_mask, epsilon, iterations)
    paid = plan * cost
    step_cost = paid.sum(-1) / plan.sum(-1).clamp_min(1e-30)  # (S, M, L): the cost per unit of each step's mass
    total = paid.sum((-1, -2))  # (S, M)
    k = min(top_k, demos.shape[0])
    best = total.topk(k, dim=1, largest=False).indices  # (S, k)
    chosen = step_cost.gather(1, best[:, :, None].expand(-1, -1, step_cost.shape[-1]))
    return -scale * chosen.mean(1) * agent_mask, total


def window_mask(lengths: torch.Tensor, starts: torch.Tensor, sizes: torch.Tensor, whole: torch.Tensor,
                longest: int) -> torch.Tensor:
    """(S, M, longest) the demonstration steps a piece is matched against: all of each demonstration for a whole
    episode, else the `sizes` steps from episode time `starts` (moved back to fit where a demonstration is
    shorter). lengths (M,), starts, sizes and whole (S,)."""
    steps = torch.arange(longest, device=lengths.device)
    lo = torch.minimum(starts[:, None], (lengths[None, :] - sizes[:, None]).clamp_min(0))  # (S, M)
    hi = torch.minimum(lo + sizes[:, None], lengths[None, :])
    inside = (steps >= lo[..., None]) & (steps < hi[..., None])
    full = steps[None, None, :] < lengths[None, :, None]
    return torch.where(whole[:, None, None], full, inside)


class OTReward:
    """The optimal-transport reward (`ot`, and `ot-subtask` with the codes); no discriminator.

    Args:
        host: the trainer (the demonstrations and q's codes of them, the settings).
        inputs: D's view of the observations, which the transport compares.
        kind: `ot`, or `ot-subtask` (codes matched too).
    """

    def __init__(self, host: RewardHost, inputs: RewardInputs, kind: str = "ot") -> None:
        self.host, self.inputs, self.cfg, self.kind = host, inputs, host.cfg.imitation, kind
        self.subtask = kind == "ot-subtask"
        if self.subtask and host.K < 2:
            raise UserError("--train.imitation.reward ot-subtask matches the agent's sub-task codes with the "
                            "demonstrations' and this policy has one code; use --train.imitation.reward ot, or "
                            "--method digail with a VAE of several codes.")
        if host.absorbing:
            raise UserError(f"--train.imitation.reward {kind} has no discriminator to score absorbing states; "
                            "drop --train.sac.absorbing or use --train.imitation.reward bce.")
        self._demos: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None
        self._pending: dict[int, list[tuple[int, np.ndarray, int, int]]] = {}
        """off-policy: per env, the (buffer position, features, code, episode time) of its episode so far"""
        self._replay: np.ndarray | None = None
        """off-policy: the reward of every buffer position (0 until its episode is scored)"""
        self._episode_t: dict[int, int] = {}
        self._last: list[float] = []

    # ------------------------------------------------------------------------------------------ the demos
    def demos(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(M, Ld, F) the demonstrations' features padded with zeros, (M, Ld) their codes (-1: padding), (M,)
        lengths; made once (D's view and q are fixed)."""
        if self._demos is None:
            expert = self.host.expert
            lengths = torch.as_tensor((expert.replay_codes >= 0).sum(1), dtype=torch.long)
            feats = self.inputs.features(expert.obs_n).detach()
            longest = int(lengths.max())
            padded = feats.new_zeros(len(lengths), longest, feats.shape[1])
            codes = torch.full((len(lengths), longest), -1, dtype=torch.long)
            start = 0
            for i, n in enumerate(lengths.tolist()):
                padded[i, :n] = feats[start:start + n]
                codes[i, :n] = expert.codes[start:start + n].cpu()
                start += n
            self._demos = (padded, codes.to(feats.device), lengths.to(feats.device))
        return self._demos

    def score(self, pieces: list[tuple[torch.Tensor, torch.Tensor, int, bool]]) -> list[torch.Tensor]:
        """Rewards of agent pieces, each (features (L, F), codes (L,), episode time of its first step, whether it
        is a whole episode)."""
        if not pieces:
            return []
        feats, codes, lengths = self.demos()
        sizes = torch.tensor([len(p[0]) for p in pieces], device=feats.device)
        longest = int(sizes.max())
        agent = feats.new_zeros(len(pieces), longest, feats.shape[-1])
        agent_codes = torch.full((len(pieces), longest), -1, dtype=torch.long, device=feats.device)
        for i, (x, c, _, _) in enumerate(pieces):
            agent[i, :len(x)] = x
            agent_codes[i, :len(c)] = c
        agent_mask = torch.arange(longest, device=feats.device)[None, :] < sizes[:, None]
        starts = torch.tensor([p[2] for p in pieces], device=feats.device)
        whole = torch.tensor([p[3] for p in pieces], device=feats.device)
        demo_mask = window_mask(lengths, starts, sizes, whole, feats.shape[1])
        times = starts[:, None] + torch.arange(longest, device=feats.device)[None, :]
        cfg = self.cfg
        with torch.no_grad():
            rews, _ = ot_step_rewards(agent, agent_mask, feats, demo_mask, epsilon=cfg.ot_epsilon,
                                      iterations=cfg.ot_iterations, top_k=cfg.ot_top_k, scale=cfg.ot_scale,
                                      agent_codes=agent_codes if self.subtask else None,
                                      demo_codes=codes if self.subtask else None,
                                      metric=cfg.ot_cost, code_penalty=cfg.ot_code_penalty, agent_times=times,
                                      time_weight=cfg.ot_time_weight, demo_lengths=lengths)
        out = [rews[i, :n] for i, n in enumerate(sizes.tolist())]
        self._last.extend(float(r.mean()) for r in out)
        return out

    # ------------------------------------------------------------------------------------------ on-policy
    def rewards(self, steps: Steps) -> torch.Tensor:
        if steps.idx is None:
            return self._rollout_rewards(steps.batch, steps.obs)
        return self._replay_rewards(steps.idx, steps.obs.device)

    def _rollout_rewards(self, batch: dict[str, torch.Tensor], obs_n: torch.Tensor) -> torch.Tensor:
        """The reward (T, N) of a rollout's steps, episode piece by piece; `obs_n` are its (T * N) flat steps."""
        T, N = batch["logp"].shape
        feats = self.inputs.features(obs_n).reshape(T, N, -1)
        done = (batch["terminated"] | batch["truncated"]).cpu().numpy()
        offset = batch.get("ep_offset")
        offsets = offset.cpu().numpy() if offset is not None else np.zeros(N, np.int64)
        pieces, where = [], []
        for n in range(N):
            ends = np.flatnonzero(done[:, n]).tolist()
            start = 0
            for end in [*ends, T - 1]:
                if end < start:
                    continue
                t0 = int(offsets[n]) if start == 0 else 0
                whole = t0 == 0 and done[end, n]
                pieces.append((feats[start:end + 1, n], batch["codes"][start:end + 1, n], t0, bool(whole)))
                where.append((n, start, end + 1))
                start = end + 1
        rews = torch.zeros(T, N, device=obs_n.device)
        for (n, a, b), r in zip(where, self.score(pieces), strict=True):
            rews[a:b, n] = r
        return rews

    # ----------------------------------------------------------------------------------------- off-policy
    def update(self, agent: Rollout | EnvStep) -> None:
        """Nothing to learn; off-policy, the steps just stored are kept until their episode ends and then scored
        (an episode under way when its env restarts is scored as the piece it is)."""
        if isinstance(agent, Rollout):
            return
        restarted = [n for n in self._pending if agent.first[n]]
        if restarted:
            self._score_pending(restarted, whole=False)
        assert agent.steps.idx is not None
        self._observe(agent.steps.idx, agent.steps.obs, agent.steps.batch["codes"], agent.done)

    def _observe(self, idx: Any, obs_n: torch.Tensor, codes: torch.Tensor, done: Any) -> None:
        """The steps just stored at buffer positions `idx` (one per env: normalised s_t, c_t, and whether the env's
        episode ended with it)."""
        if self._replay is None:
            self._replay = np.zeros(0, np.float32)
        feats = self.inputs.features(obs_n).detach().cpu().numpy()
        idx_np, codes_np = np.asarray(idx).reshape(-1), codes.cpu().numpy().reshape(-1)
        need = int(idx_np.max()) + 1
        if need > len(self._replay):  # grows with the buffer (a ring: positions are reused once it is full)
            self._replay = np.concatenate([self._replay, np.zeros(need - len(self._replay), np.float32)])
        self._replay[idx_np] = 0.0
        finished = []
        for n, (i, f, c, d) in enumerate(zip(idx_np, feats, codes_np, np.asarray(done).reshape(-1), strict=True)):
            t = self._episode_t.get(n, 0)
            self._pending.setdefault(n, []).append((int(i), f, int(c), t))
            self._episode_t[n] = t + 1
            if d:
                finished.append(n)
        if finished:
            self._score_pending(finished, whole=True)

    def _score_pending(self, envs: list[int], whole: bool) -> None:
        pieces, positions = [], []
        for n in envs:
            steps = self._pending.pop(n, [])
            self._episode_t.pop(n, None)
            if not steps:
                continue
            t0 = steps[0][3]
            pieces.append((torch.as_tensor(np.stack([s[1] for s in steps]), device=self.host.device),
                           torch.as_tensor([s[2] for s in steps], device=self.host.device), t0, whole and t0 == 0))
            positions.append(np.array([s[0] for s in steps]))
        assert self._replay is not None or not pieces
        for pos, r in zip(positions, self.score(pieces), strict=True):
            assert self._replay is not None
            self._replay[pos] = r.cpu().numpy()

    def _replay_rewards(self, idx: torch.Tensor, device: torch.device) -> torch.Tensor:
        """The scores of the buffer positions `idx`."""
        if self._replay is None:
            return torch.zeros(len(idx), device=device)
        # the steps of an episode still under way read 0 until it ends (at most one episode per env)
        return torch.from_numpy(self._replay[idx.cpu().numpy()]).to(device)

    def scalars(self) -> dict[str, float]:
        """`reward/ot_episode`: the mean reward per step of the pieces scored since the last call."""
        last, self._last = self._last, []
        return {"reward/ot_episode": float(np.mean(last)) if last else math.nan}

    # ------------------------------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        pending = [(n, s) for n, steps in sorted(self._pending.items()) for s in steps]
        feats = (np.stack([s[1] for _, s in pending]) if pending
                 else np.zeros((0, 1), np.float32))
        return {"ot": {"replay": torch.from_numpy(self._replay if self._replay is not None
                                                  else np.zeros(0, np.float32)).clone(),
                       "pending_env": torch.tensor([n for n, _ in pending], dtype=torch.long),
                       "pending_pos": torch.tensor([s[0] for _, s in pending], dtype=torch.long),
                       "pending_code": torch.tensor([s[2] for _, s in pending], dtype=torch.long),
                       "pending_t": torch.tensor([s[3] for _, s in pending], dtype=torch.long),
                       "pending_feats": torch.from_numpy(np.ascontiguousarray(feats, np.float32))}}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        own = state["ot"]
        replay = own["replay"].numpy().astype(np.float32)
        self._replay = replay.copy() if len(replay) else None
        self._pending, self._episode_t = {}, {}
        for n, pos, code, t, f in zip(own["pending_env"].tolist(), own["pending_pos"].tolist(),
                                      own["pending_code"].tolist(), own["pending_t"].tolist(),
                                      own["pending_feats"].numpy(), strict=True):
            self._pending.setdefault(n, []).append((pos, f.copy(), code, t))
            self._episode_t[n] = t + 1
