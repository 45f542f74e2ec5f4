"""Modified GradNorm (MGN), paper section III-C, eq. (8)-(15), Algorithm 1.

Shared machinery with the original GradNorm (:mod:`.gradnorm`) lives in :class:`GradNormCore`.
"""
from __future__ import annotations

import math
from contextlib import AbstractContextManager, nullcontext
from typing import Any, Mapping, Sequence

import torch
from torch import Tensor, nn

from pydantic import Field, model_validator

from ...core.params import ModelRecipe, Strict, check_lr_floor
from ...core.errors import NonFinite
from ..schedule import PlateauRule, plateau_due
from .base import LossWeighting, finite_or_raise, recipe_params, register, shared_weights

__all__ = ["GradNormCore", "MGNWeighting", "MgnParams", "finite_or_raise", "full_precision"]


class MgnParams(Strict):
    """``mgn: {alpha, lr, lr_min, authors_mode}``: Algorithm 1's settings (section III-C)."""

    alpha: float = Field(ge=0.0)
    lr: float = Field(gt=0.0)
    lr_min: float = Field(gt=0.0)
    authors_mode: bool = Field(description="reproduce the authors' public code (SPEC 7)")

    @model_validator(mode="after")
    def _lr_floor(self) -> "MgnParams":
        check_lr_floor(self.lr, self.lr_min)
        return self

_LOW = (torch.float16, torch.bfloat16)


def _retry_scales(grad_scale: float) -> tuple[float, ...]:
    """The loss scales a gradient norm is tried at: the GradScaler's, then none (1.0), where a
    float16 backward cannot overflow. With no loss scaling, 1.0 alone."""
    return (float(grad_scale), 1.0) if float(grad_scale) != 1.0 else (1.0,)


def full_precision(losses: Mapping[str, Tensor]) -> AbstractContextManager[Any]:
    """Autocast switched off on the losses' device while the gradient norms are taken (mixed
    precision, issue 15): the norms, G_i and L_MGN are then computed in float32 or wider
    whatever the caller's context. A no-op context where autocast is not on (float32 runs)."""
    first = next(iter(losses.values()), None)
    dev = first.device.type if isinstance(first, Tensor) else "cpu"
    if torch.is_autocast_enabled(dev):
        return torch.autocast(dev, enabled=False)
    return nullcontext()


def _at_least_float32(x: Tensor) -> Tensor:
    """``x`` in float32 when it is float16 / bfloat16; otherwise ``x`` itself (no new node)."""
    return x.float() if x.dtype in _LOW else x


class GradNormCore(LossWeighting):
    """Gradient-norm balancing of the loss weights (eq. 9-15), the part MGN and GradNorm share.

    One update (``_grad_w`` + the subclass step):

    1. ``n_i = ||grad_W L_i||_2`` with W = the weights of ``shared[task]``, computed with
       ``torch.autograd.grad(..., retain_graph=True)``: no ``.grad`` is written and the forward
       graph survives for the following ``total(...).backward()``.
    2. ``G_i = ||grad_W (w_i L_i)|| = w_i n_i`` (eq. 9, w_i > 0), ``G_avg = mean_i G_i`` (eq. 10).
    3. ``Lbar_i = L_i / L_i(0)`` (eq. 11), ``r_i = Lbar_i / mean_j Lbar_j`` (eq. 12).
    4. targets ``G_avg r_i^alpha``, detached (eq. 14); ``L_MGN = sum_i |target_i - G_i|`` (eq. 13);
       ``dL_MGN/dw_i = -sign(target_i - G_i) n_i``, obtained by autograd on a float64 copy of w
       only, so L_MGN moves nothing but w.
    5. a gradient step on w, then the non-positive guard and eq. (15) renormalisation:
       ``w <- max(w, floor)``, ``floor = min_weight_ratio * T`` (default 1e-3 T), then
       ``w <- T w / sum(w)``. A weight <= 0 would switch a task off or make training *maximise*
       its loss, and eq. (15) is undefined for ``sum w <= 0``; the floor keeps every task in play
       with a tiny weight (>= floor T / sum w > 0 after renormalising) and keeps sum w = T exactly.

    Mixed precision (issue 15): the norms are taken with autocast off (:func:`full_precision`),
    from losses in float32 or wider, and reduced in float64; under a float16 ``GradScaler`` the
    losses are multiplied by ``grad_scale`` before differentiation and the norms divided by it
    (a non-finite scaled norm is taken again unscaled). With ``grad_scale == 1`` and float32
    losses the computation is exactly the float32 one.

    On the device: L_i, L_i(0), the norms and w are device tensors and, without loss scaling, an
    update reads nothing on the host (GradNorm updates every step). Each norm is the same float64
    arithmetic as a Python float sum of the squared gradients' sums (from 0.0, in order) raised to
    the power 0.5 (``pow``, not ``sqrt``: the two differ in the last bit now and then).
    """

    def __init__(
        self,
        tasks: Sequence[str],
        shared: Mapping[str, Sequence[str]] | None = None,
        *,
        alpha: float,
        lr: float,
        lr_min: float,
        plateau_patience: int,
        plateau_factor: float,
        plateau_rule: PlateauRule,
        min_weight_ratio: float = 1e-3,
    ) -> None:
        super().__init__(tasks, plateau_patience=plateau_patience, plateau_factor=plateau_factor)
        self.plateau_rule: PlateauRule = plateau_rule
        self.shared: dict[str, list[str]] | None = (
            {t: list(shared[t]) for t in self.tasks} if shared is not None else None
        )
        self.alpha = float(alpha)
        self.lr = float(lr)
        self.lr_min = float(lr_min)
        if not 0.0 < min_weight_ratio < 1.0 / len(self.tasks):
            raise ValueError("min_weight_ratio must be in (0, 1/T)")
        self.min_weight_ratio = float(min_weight_ratio)
        self.L0: Tensor | None = None  # float64 (T,)
        self._pending: Tensor | None = None  # w(t+1), computed from this step, taken after its backward
        self.bad_epochs = 0
        self.n_updates = 0
        self.last: dict[str, Any] = {}  # diagnostics of the last update (float64 tensors)

    @classmethod
    def from_recipe(cls, recipe: ModelRecipe, tasks: Sequence[str], model: nn.Module | None = None,
                    **kw: Any) -> "GradNormCore":
        """The recipe's section (``params_model``) as keyword arguments, with the plateau settings
        (``kw``) and W's module names (``model.shared_layers()``, now if ``model`` is given)."""
        settings = recipe_params(recipe, cls.key, cls.params_model)
        shared = model.shared_layers() if model is not None else None
        return cls(tasks, shared, **settings.model_dump(), **kw)

    # ------------------------------------------------------------------ pieces
    def _shared_names(self, model: nn.Module) -> dict[str, list[str]]:
        if self.shared is None:
            layers = model.shared_layers()
            self.shared = {t: list(layers[t]) for t in self.tasks}
        return self.shared

    def _loss_vector(self, losses: Mapping[str, Tensor]) -> Tensor:
        missing = [t for t in self.tasks if t not in losses]
        if missing:
            raise KeyError(f"losses lack task(s) {missing}; got {sorted(losses)}")
        return torch.stack([losses[t].detach().to(torch.float64) for t in self.tasks])

    def _initial_losses(self, losses: Mapping[str, Tensor]) -> Tensor:
        """L_i(0) of eq. (11): this step's task losses (float64, detached); in a data-parallel run
        their mean over the ranks (one all-reduce, :attr:`ranks`), so every rank divides by the
        same L_i(0), that of the global batch."""
        L0 = self._loss_vector(losses)
        return L0 if self.ranks is None else self.ranks.mean_over_ranks(L0)

    def _grad_norms(self, losses: Mapping[str, Tensor], model: nn.Module) -> Tensor:
        """``n_i = ||grad_W L_i||_2`` (float64, (T,), on the device); writes no ``.grad``. Under a
        GradScaler the loss is scaled in and the norm scaled out; a scaled norm that overflowed is
        taken again unscaled (:data:`_retry_scales`), and one that is not finite even then is
        :class:`NonFinite` (read on the host: float16 runs only). Without loss scaling nothing is
        read: a non-finite norm makes non-finite weights, which the trainer's checks find."""
        names = self._shared_names(model)
        norms: list[Tensor] = []
        zero = torch.zeros((), dtype=torch.float64, device=self.device)
        with full_precision(losses):
            for t in self.tasks:
                W = shared_weights(model, names[t])
                L = _at_least_float32(losses[t])
                if not L.requires_grad:
                    norms.append(zero)
                elif not self._scaled:
                    norms.append(self._norm_device(L, W, zero))
                else:
                    norms.append(torch.tensor(self._scaled_norm(t, L, W), dtype=torch.float64, device=self.device))
        return torch.stack(norms)

    def _scaled_norm(self, task: str, L: Tensor, W: list[nn.Parameter]) -> float:
        """The norm under a float16 GradScaler's scale, retried unscaled where it overflows."""
        for scale in _retry_scales(self.grad_scale):
            n = self._norm(L * scale, W) / scale if scale != 1.0 else self._norm(L, W)
            if math.isfinite(n):
                return n
        raise NonFinite(f"non-finite {task} gradient norm for the {self.key} weights ({n})")

    @staticmethod
    def _norm(L: Tensor, W: list[nn.Parameter]) -> float:
        """``||grad_W L||_2``, squares summed in float64 (read on the host); the graph is retained."""
        grads = torch.autograd.grad(L, W, retain_graph=True, allow_unused=True)
        sq = sum(float(g.detach().double().pow(2).sum()) for g in grads if g is not None)
        return sq ** 0.5

    @staticmethod
    def _norm_device(L: Tensor, W: list[nn.Parameter], zero: Tensor) -> Tensor:
        """:meth:`_norm` on the device, the same bytes: the float64 sum from 0.0 in the same order,
        then ``pow(sq, 0.5)`` of one element (the scalar ``pow`` Python's ``**`` calls)."""
        grads = torch.autograd.grad(L, W, retain_graph=True, allow_unused=True)
        sq = zero
        for g in grads:
            if g is not None:
                sq = sq + g.detach().double().pow(2).sum()
        return torch.pow(sq, torch.full_like(sq, 0.5))

    def _targets(self, G: Tensor, L: Tensor) -> tuple[Tensor, Tensor]:
        """Eq. (10)-(14): relative inverse rates r and the detached targets ``G_avg r^alpha``."""
        L0 = self.L0 if self.L0 is not None else L
        ratio = L / L0.clamp_min(1e-12)
        r = ratio / ratio.mean().clamp_min(1e-12)
        target = (G.mean() * r.pow(self.alpha)).detach()
        return r, target

    def _renormalise(self, w: Tensor) -> Tensor:
        """Non-positive guard + eq. (15): ``w <- T max(w, floor) / sum``."""
        T = float(self.T)
        w = w.clamp_min(self.min_weight_ratio * T)
        return w * (T / w.sum())

    def _grad_w(self, losses: Mapping[str, Tensor], model: nn.Module) -> Tensor:
        """``dL_grad/dw`` (float64, (T,)) in the default (first-order, network-isolated) mode."""
        L = self._loss_vector(losses)
        n = self._grad_norms(losses, model)
        w = self.w.detach().clone().requires_grad_(True)
        G = w * n
        r, target = self._targets(G.detach(), L)
        l_grad = (target - G).abs().sum()
        (g,) = torch.autograd.grad(l_grad, w)
        self.last = {"norms": n, "G": G.detach(), "r": r, "target": target, "L": L,
                     "l_grad": l_grad.detach(), "grad_w": g.detach()}
        return g.detach()

    def after_backward(self, taken: bool = True) -> None:
        """Take the weights this step's update computed (:meth:`before_backward`): the step's
        ``total(losses).backward()`` used w(t), the next step uses w(t+1). A step the GradScaler
        skipped (``taken`` false) drops them: they came from the gradients it found overflowing."""
        pending, self._pending = self._pending, None
        if pending is not None and taken:
            self.set_weights(finite_or_raise(pending, f"{self.key} loss weights"))
            self.n_updates += 1

    # ------------------------------------------------------------------ plateau / state
    def on_epoch_end(self, improved: bool) -> None:
        """Plateau halving of the weight lr, "like the main lr" (SPEC 7): ``improved`` is the
        trainer's plateau verdict for this epoch; once ``plateau_rule`` calls for a reduction
        (:func:`~compact_perception.learning.schedule.plateau_due`: ``plateau_patience`` epochs without a
        drop, or more than that for the 'torch' rule), ``lr <- max(lr * factor, lr_min)`` and the
        count restarts."""
        if improved:
            self.bad_epochs = 0
            return
        self.bad_epochs += 1
        if plateau_due(self.bad_epochs, self.plateau_patience, self.plateau_rule):
            self.lr = max(self.lr * self.plateau_factor, self.lr_min)
            self.bad_epochs = 0

    def state_dict(self) -> dict[str, Any]:
        s = super().state_dict()
        s.update(lr=self.lr, bad_epochs=self.bad_epochs, n_updates=self.n_updates,
                 L0=None if self.L0 is None else self.L0.tolist())
        return s

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        super().load_state_dict(state)
        self.lr = float(state["lr"])
        self.bad_epochs = int(state["bad_epochs"])
        self.n_updates = int(state["n_updates"])
        self.L0 = None if state["L0"] is None else self._device_tensor(state["L0"])

    def log_values(self) -> dict[str, float]:
        out = super().log_values()
        out["lr_w"] = self.lr
        return out


@register("mgn")
class MGNWeighting(GradNormCore):
    """MGN (Algorithm 1): L_i(0) recorded at step 0 of every epoch (the mean over the ranks in a
    data-parallel run); one update of w at the last step of the epoch (``step == n_steps - 1``;
    with ``n_steps == 1`` that is the same step), by plain SGD (``w <- w - lr dL_MGN/dw``, lr 0.1
    halved on plateau down to lr_min 1e-4), then the floor and eq. (15). In the default mode L_MGN
    touches neither a network parameter nor its ``.grad`` and ``total()`` treats w as constants.

    ``authors_mode=True`` (MgnParams.authors_mode, SPEC 7) reproduces the authors' public code:
    G_i is built with ``create_graph=True`` and ``L_MGN.backward(retain_graph=True)`` is run, so
    the second-order terms ``dL_MGN/dtheta`` are *accumulated into the network's .grad* (on top of
    the later ``total().backward()``), and w's gradient is ``dL_MGN/dw + dL_total/dw`` where
    ``dL_total/dw_i = L_i`` (eq. 8; added analytically, which equals what a non-detached w in
    ``total()`` would receive from that step's backward).
    """

    capturable = True  # an ordinary step is eq. (8)'s backward with w(t); the update is at the epoch's last

    params_model = MgnParams

    def __init__(self, tasks: Sequence[str], shared: Mapping[str, Sequence[str]] | None = None, *,
                 authors_mode: bool = False, **kw: Any) -> None:
        super().__init__(tasks, shared, **kw)
        self.authors_mode = bool(authors_mode)

    def _authors_G(self, losses: Mapping[str, Tensor], model: nn.Module, w: Tensor) -> Tensor:
        """G_i = ||grad_W (w_i L_i)|| with ``create_graph=True`` (the authors' code), at the
        GradScaler's loss scale and, where that overflows a float16 backward, again unscaled
        (:data:`_retry_scales`); :class:`NonFinite` when no scale gives finite norms."""
        names = self._shared_names(model)
        for scale in _retry_scales(self.grad_scale):
            Gs = []
            for i, t in enumerate(self.tasks):
                W = shared_weights(model, names[t])
                Li = _at_least_float32(losses[t])
                if not Li.requires_grad:
                    Gs.append(w[i] * 0.0)
                    continue
                wl = w[i] * Li if scale == 1.0 else w[i] * Li * scale
                grads = torch.autograd.grad(wl, W, retain_graph=True, create_graph=True, allow_unused=True)
                sq = sum((_at_least_float32(g).pow(2).sum() for g in grads if g is not None), w[i] * 0.0)
                Gi = sq.clamp_min(1e-30).sqrt()  # no inf gradient at a zero norm
                Gs.append(Gi if scale == 1.0 else Gi / scale)
            G = torch.stack(Gs)
            if bool(torch.isfinite(G.detach()).all()):
                return G
        raise NonFinite(f"non-finite gradient norms G for the MGN weights ({G.detach().tolist()})")

    def _grad_w_authors(self, losses: Mapping[str, Tensor], model: nn.Module) -> Tensor:
        """Authors' variant: second-order terms reach the network; w also gets dL_total/dw."""
        L = self._loss_vector(losses)
        ref = losses[self.tasks[0]]
        scale = float(self.grad_scale)  # float16 GradScaler: scale in, unscale out (class doc)
        # w (and so G, L_MGN) in float32 or wider, even for float16 / bfloat16 losses
        w = self.w.detach().to(device=ref.device, dtype=torch.promote_types(ref.dtype, torch.float32))
        w.requires_grad_(True)
        with full_precision(losses):
            G = self._authors_G(losses, model, w)
            r, target = self._targets(G.detach().double(), L)
            l_mgn = (target.to(G) - G).abs().sum()
            # into w.grad AND the network's .grad (authors' code); scaled like the total loss so
            # the GradScaler's unscale_ of .grad leaves the second-order terms at their value (an
            # overflow there is the scaler's to find: it skips the step, and these weights with it)
            (l_mgn if scale == 1.0 else l_mgn * scale).backward(retain_graph=True)
            gw = w.grad.detach().double()
            gw = gw if scale == 1.0 else gw / scale
            if scale != 1.0 and not bool(torch.isfinite(gw).all()):  # w's share taken again, unscaled
                gw = torch.autograd.grad(l_mgn, w, retain_graph=True)[0].detach().double()
        g = gw + L  # + dL_total/dw_i = L_i
        self.last = {"G": G.detach().double(), "r": r, "target": target, "L": L,
                     "l_grad": l_mgn.detach(), "grad_w": g}
        return g

    @classmethod
    def needs_double_backward(cls, settings: Any) -> bool:
        """The authors' update differentiates L_MGN through G's gradients (``create_graph``)."""
        return bool(settings.authors_mode)

    def before_backward(self, step: int, n_steps: int, losses: Mapping[str, Tensor], model: nn.Module) -> None:
        """Algorithm 1: record L_i(0) at step 0; at step n_steps - 1 compute w(t+1), which
        :meth:`after_backward` takes once that step's backward has used w(t)."""
        if n_steps < 1 or not 0 <= step < n_steps:
            raise ValueError(f"step {step} outside [0, n_steps={n_steps})")
        if step == 0:
            self.L0 = self._initial_losses(losses)
        if step == n_steps - 1:
            g = self._grad_w_authors(losses, model) if self.authors_mode else self._grad_w(losses, model)
            self._pending = self._renormalise(self.w - self.lr * g)

    def state_dict(self) -> dict[str, Any]:
        s = super().state_dict()
        s["authors_mode"] = self.authors_mode
        return s
