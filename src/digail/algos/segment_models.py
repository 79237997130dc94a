"""What hard EM fits to a segmentation (`digail.algos.segment_init`), its M-step: the normalised state features
[s_n, 1] and actions of every step (`_design`), one linear sub-task policy per code (`_LinearPolicies`) and the
macro-policy that prices the switches when they are learned (`_Transitions`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from digail.data.trajectory import Trajectory


def _features(trajs: Sequence[Trajectory], mean: np.ndarray, std: np.ndarray) -> list[np.ndarray]:
    out = []
    for t in trajs:
        obs = np.asarray(t.obs[:len(t)], np.float64).reshape(len(t), -1)
        out.append(np.c_[(obs - mean) / std, np.ones(len(t))])
    return out


class _Transitions:
    """The start's macro-policy p(c_t | c_{t-1}, s_t) (module docstring): per previous code a softmax-linear model
    of the next code on x = [s_n, 1], mixed with weight `base` with the fixed model (switch with probability
    1 / T, to any other code alike)."""

    def __init__(self, k: int, dim_x: int, mean_len: float, ridge: float = 1e-3, base: float = 0.5) -> None:
        self.k, self.base = k, base
        # light ridge: a switch the state predicts should become cheap; the mixture, not the ridge, bounds the rest
        self.ridge = np.r_[np.full(dim_x - 1, ridge), 1e-6]
        self.w = np.zeros((k, dim_x, k))
        p_switch = 1.0 / mean_len
        self.fixed = np.full((k, k), math.log(p_switch / max(k - 1, 1)))
        np.fill_diagonal(self.fixed, math.log(1.0 - p_switch))

    def fit(self, x: np.ndarray, seg: Sequence[np.ndarray], bounds: np.ndarray) -> None:
        prev, nxt, rows = _pairs(seg, bounds)
        for j in range(self.k):
            sel = prev == j
            if sel.any():  # an unused code keeps its last model
                self.w[j] = _softmax_lbfgs(x[rows[sel]], nxt[sel], self.w[j], self.ridge, TRANSITION_STEPS,
                                           TRANSITION_GTOL)

    def logprob(self, x: np.ndarray) -> np.ndarray:
        """(T, K, K) log p(c_t = k | c_{t-1} = j, s_t) for the rows of `x`."""
        z = np.einsum("td,jdk->tjk", x, self.w)
        z = z - z.max(-1, keepdims=True)
        learned = z - np.log(np.exp(z).sum(-1, keepdims=True))
        return np.logaddexp(math.log(1 - self.base) + learned, math.log(self.base) + self.fixed[None])


def _pairs(seg: Sequence[np.ndarray], bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(c_{t-1}, c_t, row of step t) over every step but each episode's first."""
    return (np.concatenate([c[:-1] for c in seg]), np.concatenate([c[1:] for c in seg]),
            np.concatenate([np.arange(bounds[i] + 1, bounds[i + 1]) for i in range(len(seg))]))


ACTION_MODELS = ("auto", "gaussian")
"""how the start's sub-task policies model continuous actions (`VAEConfig.init_actions`): `auto` reads two facts off
the demonstrations' actions, per dimension, and models them (`_ActionKinds`); `gaussian` is one Gaussian per
dimension throughout (how the runs before `auto` were made)"""

CENSOR_SHARE = 0.02
"""an action dimension whose lowest or highest value is taken by at least this share of the steps is read as
clipped at that value (`_ActionKinds`)"""

FEW_VALUES = 4
"""an action dimension whose at most this many values cover `FEW_VALUES_COVER` of the steps is a command from a
small set (a gripper's open / close), modelled by a softmax over its values (`_ActionKinds`)"""

FEW_VALUES_COVER = 0.99


class _ActionKinds:
    """What each continuous action dimension is, read off the demonstrations (`ACTION_MODELS`, `auto`).

    Clipped dimensions: scripted experts (Meta-World's, Fetch's) send a proportional controller's output clipped to
    the action bounds. At the bound the action only says the controller's output was beyond it, so a step there is
    scored by how far the prediction falls short of the bound and not at all past it (a censored, Tobit-like
    residual). Without it a phase whose clipped output changes regime half-way (first saturated, then
    proportional) costs a linear policy more than two codes do, and the start cut such phases in two.

    Few-valued dimensions: a gripper command takes two or three values and switches where the object is reached,
    which need not be where the arm's sub-task changes. As a Gaussian, a code that never sees the switch fits it
    exactly and pays for it nothing, so the start cut the arm's phases where the gripper switched (Meta-World's
    pick-place: reach and descend merged, descend cut at the grasp). A softmax over the values, linear in the
    state, explains a switch that the state predicts within one code."""

    def __init__(self, a: np.ndarray) -> None:
        lo, hi = a.min(0), a.max(0)
        self.lo = np.where((np.abs(a - lo) < 1e-6).mean(0) >= CENSOR_SHARE, lo, -np.inf)
        self.hi = np.where((np.abs(a - hi) < 1e-6).mean(0) >= CENSOR_SHARE, hi, np.inf)
        self.values: dict[int, np.ndarray] = {}
        for d in range(a.shape[1]):
            vals, counts = np.unique(np.round(a[:, d], 6), return_counts=True)
            top = np.argsort(counts)[::-1][:FEW_VALUES]
            if len(vals) > 1 and counts[top].sum() >= FEW_VALUES_COVER * len(a):
                self.values[d] = np.sort(vals[top])
        self.gaussian = np.array([d not in self.values for d in range(a.shape[1])])

    def index(self, a: np.ndarray, d: int) -> np.ndarray:
        """Each step's value of few-valued dimension `d` as an index into its values (the nearest)."""
        return np.abs(a[:, d, None] - self.values[d][None]).argmin(1)

    def residual(self, a: np.ndarray, pred: np.ndarray) -> np.ndarray:
        """a - pred, but 0 where a sits at a clipped bound and pred lies beyond it (broadcasts over codes)."""
        at_hi = (a >= self.hi - 1e-6) & (pred > a)
        at_lo = (a <= self.lo + 1e-6) & (pred < a)
        return np.where(at_hi | at_lo, 0.0, a - pred)


class _LinearPolicies:
    """One linear policy per code on features x = [s_n, 1]: Gaussian (continuous) or softmax (discrete); with
    `actions="auto"` a continuous dimension may be clipped or few-valued (`_ActionKinds`)."""

    def __init__(self, k: int, dim_x: int, act_dim: int, discrete: bool, ridge: float = 1e-3,
                 shared_variance: bool = True, outlier_share: float = 0.0, actions: str = "gaussian") -> None:
        if actions not in ACTION_MODELS:
            raise ValueError(f"unknown action model {actions!r}; choose one of {', '.join(ACTION_MODELS)}.")
        self.k, self.discrete, self.shared_variance, self.outlier_share = k, discrete, shared_variance, outlier_share
        self.actions = actions
        self.kinds: _ActionKinds | None = None
        self.log_span = np.zeros(act_dim)  # log of each action dimension's range in the fitted steps
        # the state weights shrink towards a constant policy per code; the bias (last feature) hardly at all
        self.ridge = np.r_[np.full(dim_x - 1, ridge), 1e-6]
        self.w = np.zeros((k, dim_x, act_dim))
        self.w_values: dict[int, np.ndarray] = {}
        self.log_var = np.zeros((k, act_dim))

    def fit(self, x: np.ndarray, a: np.ndarray, codes: np.ndarray) -> None:
        sq_resid = np.zeros_like(self.log_var)
        if not self.discrete:
            self.log_span = np.log(np.maximum(a.max(0) - a.min(0), 1e-6))
            if self.actions == "auto" and self.kinds is None:  # read once, from the steps first fitted
                self.kinds = _ActionKinds(a)
                self.w_values = {d: np.zeros((self.k, x.shape[1], len(v))) for d, v in self.kinds.values.items()}
        for j in range(self.k):
            sel = codes == j
            if sel.sum() == 0:
                continue  # an unused code keeps its last policy
            xj, aj = x[sel], a[sel]
            if self.discrete:
                self.w[j] = _softmax_regression(xj, aj, self.w.shape[2], self.w[j], self.ridge)
                continue
            gram = xj.T @ xj + len(xj) * np.diag(self.ridge)
            censored = self.kinds is not None and bool(np.isfinite(np.r_[self.kinds.lo, self.kinds.hi]).any())
            if not censored or not self.w[j].any():
                self.w[j] = np.linalg.solve(gram, xj.T @ aj)
            if censored:
                assert self.kinds is not None
                self.w[j] = _censored_least_squares(xj, aj, self.w[j], len(xj) * np.diag(self.ridge), self.kinds)
            resid = aj - xj @ self.w[j] if self.kinds is None else self.kinds.residual(aj, xj @ self.w[j])
            sq_resid[j] = (resid ** 2).sum(0)
            if not self.shared_variance:
                self.log_var[j] = np.log(np.maximum(resid.var(0), 1e-4))
            if self.kinds is not None:
                for d, w in self.w_values.items():
                    w[j] = _softmax_lbfgs(xj, self.kinds.index(aj, d), w[j], self.value_ridge, VALUE_STEPS)
        if not self.discrete and self.shared_variance:
            # one noise level per action dimension for all codes (module docstring: why not one per code)
            self.log_var[:] = np.log(np.maximum(sq_resid.sum(0) / len(x), 1e-4))

    @property
    def value_ridge(self) -> np.ndarray:
        """the few-valued dimensions' softmax ridge: light, so that a switch the state predicts becomes cheap"""
        return np.r_[np.full(len(self.ridge) - 1, VALUE_RIDGE), 1e-6]

    def loglik(self, x: np.ndarray, a: np.ndarray) -> np.ndarray:
        """(T, K) log-likelihood of each step's action under each code's policy."""
        out = np.einsum("td,kda->tka", x, self.w)
        if self.discrete:
            out = out - out.max(-1, keepdims=True)
            logp = out - np.log(np.exp(out).sum(-1, keepdims=True))
            return np.take_along_axis(logp, a.astype(np.int64)[:, None, None].repeat(self.k, 1), 2)[..., 0]
        var = np.exp(self.log_var)[None]
        resid = a[:, None, :] - out if self.kinds is None else self.kinds.residual(a[:, None, :], out)
        per_dim = -0.5 * ((resid ** 2) / var + self.log_var[None] + math.log(2 * math.pi))
        if self.outlier_share > 0:
            # a share of the steps uniform over the range: what one unpredictable step can cost is capped
            per_dim = np.logaddexp(math.log1p(-self.outlier_share) + per_dim,
                                   math.log(self.outlier_share) - self.log_span)
        if self.kinds is None:
            return per_dim.sum(-1)
        total = per_dim[..., self.kinds.gaussian].sum(-1)
        for d, w in self.w_values.items():
            z = np.einsum("td,kdv->tkv", x, w)
            z = z - z.max(-1, keepdims=True)
            logp = z - np.log(np.exp(z).sum(-1, keepdims=True))
            idx = self.kinds.index(a, d)
            lp = np.take_along_axis(logp, idx[:, None, None].repeat(self.k, 1), 2)[..., 0]
            if self.outlier_share > 0:
                lp = np.logaddexp(math.log1p(-self.outlier_share) + lp,
                                  math.log(self.outlier_share / w.shape[2]))
            total = total + lp
        return total


CENSOR_ROUNDS = 8
"""most Newton steps of the censored least squares (`_censored_least_squares`) per fit; each fit starts from the
code's last weights"""


def _censored_least_squares(x: np.ndarray, a: np.ndarray, w: np.ndarray, penalty: np.ndarray,
                            kinds: _ActionKinds) -> np.ndarray:
    """Weights minimising sum over steps of `kinds.residual(a, x w)`^2 plus w' `penalty` w, per action dimension:
    a step at a clipped bound counts only while the prediction falls short of it.

    The loss is convex and piecewise quadratic; each Newton step solves least squares on the steps that count at
    the current weights (those inside the bounds, and those at a bound the prediction does not reach, with the
    bound as target) and stops when that set no longer changes: exact in a few steps, where imputing the clipped
    steps' targets converges slowly when most steps are clipped."""
    w = w.copy()
    for d in range(a.shape[1]):
        if np.isinf(kinds.lo[d]) and np.isinf(kinds.hi[d]):
            continue
        at_hi, at_lo = a[:, d] >= kinds.hi[d] - 1e-6, a[:, d] <= kinds.lo[d] + 1e-6
        counted = None
        for _ in range(CENSOR_ROUNDS):
            pred = x @ w[:, d]
            now = ~((at_hi & (pred > a[:, d])) | (at_lo & (pred < a[:, d])))
            if counted is not None and np.array_equal(now, counted):
                break
            counted = now
            xc = x[counted]
            w[:, d] = np.linalg.solve(xc.T @ xc + penalty, xc.T @ a[counted, d])
    return w

VALUE_RIDGE = 1e-3
"""ridge on the state weights of a few-valued action dimension's softmax (`_LinearPolicies.value_ridge`)"""

VALUE_STEPS = 15
"""L-BFGS iterations per fit of a few-valued dimension's softmax; each fit starts from the code's last weights,
so hard EM's rounds add up to a converged fit where the codes settle"""


TRANSITION_STEPS = 300
"""L-BFGS iterations per fit of one previous code's switch model (`_Transitions.fit`), from its last weights"""
TRANSITION_GTOL = 1e-7
"""the switch model's fit stops when no gradient entry exceeds this"""


def _softmax_lbfgs(x: np.ndarray, idx: np.ndarray, w0: np.ndarray, ridge: np.ndarray, steps: int,
                   gtol: float = 1e-5) -> np.ndarray:
    """Weights (dim_x, n) of a softmax over n values, linear in `x`, fitted to the value indices `idx` by scipy's
    L-BFGS from `w0` (mean cross-entropy plus the ridge). NumPy and SciPy, not torch: the fits are small and many,
    and torch's optimiser costs more per call than the arithmetic."""
    from scipy.optimize import minimize

    n = w0.shape[1]
    onehot = np.eye(n)[idx]

    def loss(flat: np.ndarray) -> tuple[float, np.ndarray]:
        w = flat.reshape(w0.shape)
        z = x @ w
        z = z - z.max(1, keepdims=True)
        logp = z - np.log(np.exp(z).sum(1, keepdims=True))
        value = -float((onehot * logp).sum()) / len(x) + float((ridge[:, None] * w ** 2).sum())
        grad = x.T @ (np.exp(logp) - onehot) / len(x) + 2 * ridge[:, None] * w
        return value, grad.ravel()

    res = minimize(loss, w0.ravel(), jac=True, method="L-BFGS-B", options={"maxiter": steps, "gtol": gtol})
    return np.asarray(res.x).reshape(w0.shape)


def _softmax_regression(x: np.ndarray, a: np.ndarray, n: int, w0: np.ndarray, ridge: np.ndarray,
                        steps: int = 60) -> np.ndarray:
    xt = torch.as_tensor(x, dtype=torch.float64)
    at = torch.as_tensor(a, dtype=torch.int64).reshape(-1)
    w = torch.tensor(w0, dtype=torch.float64, requires_grad=True)
    ridge_t = torch.as_tensor(ridge, dtype=torch.float64)
    opt = torch.optim.LBFGS([w], max_iter=steps, line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        opt.zero_grad()
        loss = torch.nn.functional.cross_entropy(xt @ w, at) + (ridge_t[:, None] * w ** 2).sum()
        loss.backward()
        return loss

    opt.step(closure)
    return w.detach().numpy()


def _design(trajs: Sequence[Trajectory], discrete: bool, n_act: int | None = None, mean: np.ndarray | None = None,
            std: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, int, np.ndarray, np.ndarray]:
    """Features [s_n, 1] and actions of all steps (normalised with `mean` and `std`, by default the demos' own),
    the number of discrete actions (or action dimensions) and the normalisation."""
    if mean is None or std is None:
        obs = np.concatenate([np.asarray(t.obs[:len(t)], np.float64).reshape(len(t), -1) for t in trajs])
        mean, std = obs.mean(0), obs.std(0) + 1e-6
    x = np.concatenate(_features(trajs, mean, std))
    if discrete:
        a = np.concatenate([np.asarray(t.acts).astype(np.int64).reshape(-1) for t in trajs])
        n = max(n_act or 0, int(a.max()) + 1)
    else:
        a = np.concatenate([np.asarray(t.acts, np.float64).reshape(len(t), -1) for t in trajs])
        n = a.shape[1]
    return x, a, n, mean, std
