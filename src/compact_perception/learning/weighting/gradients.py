"""Per-task gradients for the gradient-surgery methods (:mod:`.pcgrad`, :mod:`.cagrad`).

T ``torch.autograd.grad`` passes through the retained graph give each task's gradient; the
T x T Gram matrix of the shared part is taken in float64; the combined update ``sum_k c_k g_k``
is written into ``.grad``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import torch
from torch import Tensor, nn

__all__ = ["TaskGradients", "task_gradients", "shared_gram", "write_combination", "unweighted_total"]


@dataclass
class TaskGradients:
    """Per-task gradients of one step. ``per_task[i][k]``: gradient of (scaled) task loss ``i``
    w.r.t. ``params[k]`` (``None`` when that loss does not reach the parameter); ``aux[k]``: the
    gradient of the non-task losses (``aux_*``, weight 1); ``shared[k]``: two or more tasks
    reach ``params[k]``."""

    params: list[nn.Parameter]
    per_task: list[list[Tensor | None]]
    aux: list[Tensor | None]
    shared: list[bool]


def task_gradients(losses: Mapping[str, Tensor], tasks: Sequence[str], model: nn.Module,
                   scale: Callable[[Tensor], Tensor]) -> TaskGradients:
    """``torch.autograd.grad`` of ``scale(L_i)`` for every task (in task order), then of
    ``scale(sum of the non-task losses)``, w.r.t. every trainable parameter; the graph is
    retained until the last call. Writes no ``.grad``. A loss that needs no gradient gives
    ``None`` everywhere."""
    missing = [t for t in tasks if t not in losses]
    if missing:
        raise KeyError(f"losses lack task(s) {missing}; got {sorted(losses)}")
    params = [p for p in model.parameters() if p.requires_grad]
    extra = [v for k, v in losses.items() if k not in tasks]
    aux_loss: Tensor | None = None
    for v in extra:
        aux_loss = v if aux_loss is None else aux_loss + v
    jobs: list[Tensor | None] = [losses[t] if losses[t].requires_grad else None for t in tasks]
    jobs.append(aux_loss if aux_loss is not None and aux_loss.requires_grad else None)
    last = max((i for i, j in enumerate(jobs) if j is not None), default=-1)
    grads: list[list[Tensor | None]] = []
    for i, loss in enumerate(jobs):
        if loss is None:
            grads.append([None] * len(params))
            continue
        got = torch.autograd.grad(scale(loss), params, retain_graph=i < last, allow_unused=True)
        grads.append(list(got))
    per_task, aux = grads[:-1], grads[-1]
    shared = [sum(per_task[i][k] is not None for i in range(len(tasks))) >= 2 for k in range(len(params))]
    return TaskGradients(params, per_task, aux, shared)


def shared_gram(tg: TaskGradients) -> Tensor:
    """``Q_ij = g_i . g_j`` over the shared parameters (float64, (T, T), on the gradients' device:
    nothing is read on the host); a task that does not reach a shared parameter contributes zeros
    there."""
    T = len(tg.per_task)
    rows = []
    for i in range(T):
        parts = []
        for k, p in enumerate(tg.params):
            if tg.shared[k]:
                g = tg.per_task[i][k]
                parts.append(torch.zeros(p.numel(), dtype=torch.float64, device=p.device) if g is None
                             else g.detach().reshape(-1).to(torch.float64))
        rows.append(torch.cat(parts) if parts else torch.zeros(1, dtype=torch.float64))
    Q = torch.zeros(T, T, dtype=torch.float64, device=rows[0].device)
    for i in range(T):  # elementwise products and sums: deterministic on CPU and CUDA (no cuBLAS)
        for j in range(i, T):
            Q[i, j] = Q[j, i] = (rows[i] * rows[j]).sum()
    return Q


def write_combination(tg: TaskGradients, coeffs: Sequence[float] | Tensor) -> None:
    """Write ``sum_k coeffs[k] g_k`` (shared parameters) or ``sum_k g_k`` (parameters at most one
    task reaches), plus the non-task gradient, into ``.grad``: added to an existing ``.grad``,
    else set. Parameters no loss reaches are left alone. ``coeffs``: Python floats, or a float64
    tensor on the device (not read): cast once to the gradient's dtype, each coefficient scales a
    gradient as its Python float did (rounded to that dtype, then one multiply)."""
    cast: dict[torch.dtype, tuple[Tensor, ...]] = {}  # a tensor's coefficients per gradient dtype, cast once
    for k, p in enumerate(tg.params):
        acc: Tensor | None = None
        for i, col in enumerate(tg.per_task):
            g = col[k]
            if g is None:
                continue
            if isinstance(coeffs, Tensor):
                if g.dtype not in cast:
                    cast[g.dtype] = coeffs.to(g.dtype).unbind()
                c: Tensor | float = cast[g.dtype][i]
            else:
                c = float(coeffs[i])
            term = g * c if tg.shared[k] else g
            acc = term if acc is None else acc + term
        if tg.aux[k] is not None:
            acc = tg.aux[k] if acc is None else acc + tg.aux[k]
        if acc is None:
            continue
        if p.grad is None:
            p.grad = acc.detach()
        else:
            p.grad.add_(acc.detach())


def unweighted_total(losses: Mapping[str, Tensor], tasks: Sequence[str]) -> Tensor:
    """``sum_i L_i`` + the non-task losses, detached (what the gradient methods report)."""
    total = sum(losses[t] for t in tasks)
    for k, v in losses.items():
        if k not in tasks:
            total = total + v
    return total.detach()
