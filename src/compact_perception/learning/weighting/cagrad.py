"""CAGrad: conflict-averse gradient descent (Liu, Liu, Jin, Stone, Liu, NeurIPS 2021, "Conflict-averse
gradient descent for multi-task learning", section 3 and Algorithm 1).

Per training step, with the task gradients ``g_i`` of the shared parameters (T backward passes,
see :mod:`.pcgrad` for what "shared" means here), ``g0 = (1/T) sum_i g_i`` and
``phi = c^2 ||g0||^2``, the update direction is

    w* = argmin_{w in simplex} F(w),   F(w) = g_w . g0 + sqrt(phi) ||g_w||,   g_w = sum_i w_i g_i
    d  = g0 + sqrt(phi) / ||g_w*|| g_w*  =  sum_i (1/T + sqrt(phi) w*_i / ||g_w*||) g_i.

``d`` is used as is, as in the paper; the authors' code divides it by ``1 + c^2`` (a rescaling
of the step, which changes the effective learning rate), which is not done here. The task-specific
parameters get the plain sum of their task gradients (as in the authors' code, where only the
shared parameters' gradient is replaced). ``c = 0`` gives ``d = g0``, the mean gradient.

The inner problem is T-dimensional and is solved on the T x T Gram matrix ``Q_ij = g_i . g_j``
(float64) by :func:`cagrad_coefficients`: an exact active-set enumeration (every face of the
simplex, closed-form stationary point of F on it), in plain Python floats, so the result is the
same bytes on every machine that computes the same Gram matrix.
"""
from __future__ import annotations

import math
from typing import Any, Callable, Mapping, Sequence

import torch
from pydantic import Field
from torch import Tensor, nn

from ...core.params import Strict
from .base import LossWeighting, register
from .gradients import shared_gram, task_gradients, unweighted_total, write_combination

__all__ = ["CAGradParams", "CAGradWeighting", "cagrad_coefficients"]


def _solve(A: list[list[float]], rhs: list[float]) -> list[float] | None:
    """``A x = rhs`` by Gaussian elimination with partial pivoting; ``None`` if a pivot is 0."""
    n = len(rhs)
    M = [list(A[r]) + [rhs[r]] for r in range(n)]
    for col in range(n):
        piv = max(range(col, n), key=lambda r: abs(M[r][col]))
        if M[piv][col] == 0.0:
            return None
        M[col], M[piv] = M[piv], M[col]
        for r in range(col + 1, n):
            f = M[r][col] / M[col][col]
            for k in range(col, n + 1):
                M[r][k] -= f * M[col][k]
    x = [0.0] * n
    for r in range(n - 1, -1, -1):
        x[r] = (M[r][n] - sum(M[r][k] * x[k] for k in range(r + 1, n))) / M[r][r]
    return x


def _face_point(Q: list[list[float]], b: list[float], lam: float, S: list[int]) -> list[float] | None:
    """Stationary point of ``b.w + lam sqrt(w^T Q w)`` on the affine hull of face ``S``
    (``sum w = 1``), or ``None`` if it has none with ``||g_w|| > 0`` and ``w >= 0``.

    With ``u = Q_S^-1 1``, ``v = Q_S^-1 b_S``, ``a = 1.u``, ``beta = 1.v``, ``gamma = b_S.v``,
    stationarity ``b + lam Q w / ||g_w|| = mu 1`` and ``sum w = 1`` give
    ``w = (mu u - v) / r`` with ``r = sqrt(beta^2 - a (gamma - lam^2))``, ``mu = (beta + r) / a``.
    A ridge of 1e-12 max_i Q_ii keeps ``Q_S`` invertible when gradients are dependent."""
    eps = 1e-12 * max(Q[i][i] for i in range(len(Q)))
    QS = [[Q[i][j] + (eps if i == j else 0.0) for j in S] for i in S]
    u = _solve(QS, [1.0] * len(S))
    v = _solve(QS, [b[i] for i in S])
    if u is None or v is None:
        return None
    a, beta = sum(u), sum(v)
    gamma = sum(b[i] * vi for i, vi in zip(S, v))
    if not a > 0.0:
        return None
    disc = beta * beta - a * (gamma - lam * lam)
    if not disc > 0.0:
        return None
    r = math.sqrt(disc)
    mu = (beta + r) / a
    wS = [(mu * ui - vi) / r for ui, vi in zip(u, v)]
    if min(wS) < -1e-9:
        return None
    wS = [max(x, 0.0) for x in wS]
    tot = sum(wS)
    if not tot > 0.0:
        return None
    w = [0.0] * len(Q)
    for i, x in zip(S, wS):
        w[i] = x / tot
    return w


def cagrad_coefficients(gram: Sequence[Sequence[float]], c: float) -> tuple[list[float], list[float]]:
    """CAGrad's inner problem on the Gram matrix ``gram`` (T x T, ``g_i . g_j``).

    Returns ``(w, coeffs)``: the minimiser ``w*`` of F over the simplex and the coefficients of
    ``d = sum_k coeffs[k] g_k``, ``coeffs[k] = 1/T + c ||g0|| w*_k / ||g_w*||``.

    Everything is scaled by ``||g0||^2 = 1^T Q 1 / T^2`` first (the result does not depend on a
    common scale of the gradients, e.g. a loss scaler's). The minimum over the simplex is the
    best, by F, of the vertices and of the stationary points of F on every face (2^T - 1 faces;
    the minimiser is such a point of the face it lies inside); ties keep the first face in
    bit-mask order. Degenerate cases: ``g0 = 0`` (or a non-finite Gram matrix) gives
    ``w = coeffs = 1/T``; ``g_w* = 0`` (zero in the convex hull of the gradients, where ``d`` is
    undefined) gives ``coeffs = 1/T`` (``d = g0``).
    """
    T = len(gram)
    Q = [[float(x) for x in row] for row in gram]
    uniform = [1.0 / T] * T
    g0sq = sum(sum(row) for row in Q) / (T * T)
    if not (math.isfinite(g0sq) and g0sq > 0.0) or not all(math.isfinite(x) for row in Q for x in row):
        return list(uniform), list(uniform)
    Qn = [[x / g0sq for x in row] for row in Q]  # now ||g0|| = 1 and sqrt(phi) = c
    b = [sum(row) / T for row in Qn]  # g_i . g0

    def quad(w: list[float]) -> float:
        return max(sum(w[i] * Qn[i][j] * w[j] for i in range(T) for j in range(T)), 0.0)

    def F(w: list[float]) -> float:
        return sum(bi * wi for bi, wi in zip(b, w)) + c * math.sqrt(quad(w))

    best_w: list[float] | None = None
    best_f = math.inf
    for mask in range(1, 1 << T):
        S = [i for i in range(T) if mask >> i & 1]
        if len(S) == 1:
            w: list[float] | None = [float(i == S[0]) for i in range(T)]
        else:
            w = _face_point(Qn, b, c, S)
        if w is None:
            continue
        f = F(w)
        if f < best_f:
            best_w, best_f = w, f
    assert best_w is not None  # the vertices are always candidates
    n_w = math.sqrt(quad(best_w))
    if not n_w > 1e-12:
        return best_w, list(uniform)
    return best_w, [1.0 / T + c * wi / n_w for wi in best_w]


class CAGradParams(Strict):
    """``cagrad: {c: 0.4}``: the radius ratio c (the paper's default 0.4; 0 = mean gradient)."""

    c: float = Field(ge=0.0)


@register("cagrad")
class CAGradWeighting(LossWeighting):
    """CAGrad (Liu et al. 2021) on the shared parameters; see the module docstring.

    ``w`` after a step: the coefficients of ``d`` in terms of the task gradients,
    ``w_i = 1/T + c ||g0|| w*_i / ||g_w*||`` (they multiply the shared parameters' task
    gradients; task-specific parameters get weight 1). ``log_values`` reports the mean of these
    over the last finished epoch's steps. :meth:`backward` returns the unweighted sum of the
    losses. Note ``sum_i w_i = 1 + c ||g0|| / ||g_w*||``: the shared update is on the scale of the
    *mean* task gradient (the paper's g0), not of eq. (8)'s sum with w = 1.

    Float16 ``GradScaler``: every task loss is scaled before differentiation (the coefficients do
    not depend on a common scale); a non-finite Gram matrix (overflow) makes the update the plain
    sum, whose non-finite values make the scaler skip the step, and leaves ``w`` as it was.

    Host reads: one per step, the T x T Gram matrix (taken on the device). The inner problem's
    exact active-set enumeration (pivoting, data-dependent faces) runs on its Python floats, which
    keeps its results the bytes they are; a device version would be another algorithm's rounding.
    """

    params_model = CAGradParams

    def __init__(self, tasks: Sequence[str], *, c: float, plateau_patience: int, plateau_factor: float) -> None:
        super().__init__(tasks, plateau_patience=plateau_patience, plateau_factor=plateau_factor)
        if not c >= 0.0:
            raise ValueError(f"CAGrad c must be >= 0, got {c}")
        self.c = float(c)
        self.w = torch.full((self.T,), 1.0 / self.T, dtype=torch.float64)
        self.epoch_sum = [0.0] * self.T
        self.epoch_steps = 0
        self.epoch_mean: list[float] | None = None
        self.last: dict[str, Any] = {}

    def backward(self, losses: Mapping[str, Tensor], model: nn.Module,
                 scale: Callable[[Tensor], Tensor] = lambda t: t) -> Tensor:
        """T per-task backward passes, ``d`` on the shared parameters, ``.grad`` written."""
        tg = task_gradients(losses, self.tasks, model, scale)
        gram = shared_gram(tg)
        Q = gram.tolist()  # the step's one host read: the inner problem is solved in Python floats
        if all(math.isfinite(x) for row in Q for x in row):
            w_star, coeffs = cagrad_coefficients(Q, self.c)
            self.w = torch.tensor(coeffs, dtype=torch.float64, device=self.device)
            self.epoch_sum = [s + x for s, x in zip(self.epoch_sum, coeffs)]
            self.epoch_steps += 1
            self.last = {"gram": gram, "w_star": torch.tensor(w_star, dtype=torch.float64), "coeffs": self.w.clone()}
        else:
            coeffs = [1.0] * self.T
            self.last = {"gram": gram, "overflow": True}
        write_combination(tg, coeffs)
        return unweighted_total(losses, self.tasks)

    def on_epoch_end(self, improved: bool) -> None:
        """Closes the epoch's mean of the effective weights (nothing else adapts)."""
        if self.epoch_steps:
            self.epoch_mean = [s / self.epoch_steps for s in self.epoch_sum]
        self.epoch_sum = [0.0] * self.T
        self.epoch_steps = 0

    def state_dict(self) -> dict[str, Any]:
        s = super().state_dict()
        s.update(c=self.c, epoch_sum=list(self.epoch_sum), epoch_steps=self.epoch_steps,
                 epoch_mean=None if self.epoch_mean is None else list(self.epoch_mean))
        return s

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        super().load_state_dict(state)
        if float(state["c"]) != self.c:
            raise ValueError(f"state is for CAGrad c = {state['c']}, this weighting has c = {self.c}")
        self.epoch_sum = [float(x) for x in state["epoch_sum"]]
        self.epoch_steps = int(state["epoch_steps"])
        self.epoch_mean = None if state["epoch_mean"] is None else [float(x) for x in state["epoch_mean"]]

    def log_values(self) -> dict[str, float]:
        """``w_<task>``: the effective weights, averaged over the last finished epoch."""
        if self.epoch_mean is None:
            return super().log_values()
        return {f"w_{t}": float(v) for t, v in zip(self.tasks, self.epoch_mean)}
