"""One epoch of paper section IV-D: the training steps (with the loss weighting's step protocol of
section III-C, :mod:`compact_perception.weighting`) and the validation pass, each averaged over
every process's frames.

A run that diverges stops: a training loss that is not finite stops it before that step's update,
a non-finite validation loss or score before the epoch is recorded or saved, with one line
naming the run folder, the epoch and the loss (:class:`RunError`); ``last.pt`` stays at the last
finished epoch.
"""
from __future__ import annotations

import math
from typing import Any

import torch
from tqdm.auto import tqdm

from . import distributed as ddp
from ..core.errors import NonFinite, RunError
from ..data import set_epoch, to_device
from ..losses import scale_de_loss
from ..metrics import compute_metrics, scores_from_means, total_metric_partial
from .precision import autocast_context, batch_to_channels_last, float_outputs
from .state import RunState

__all__ = ["NonFinite", "selection_score", "split_scores", "evaluate_split", "train_epoch", "train_step", "validate"]


def selection_score(metrics: dict[str, float]) -> float:
    """Validation score used for the schedule, early stopping and the best checkpoint.

    It is the total metric TM (eq. 6) over the tasks the model performs: equal to TM for
    the compact model, and to the model's own share of TM for a baseline.
    """
    return total_metric_partial(metrics)


def split_scores(means: dict[str, float]) -> dict[str, float]:
    """A split's mean scores with TM and MV recomputed from the four means (eq. 6-7, as the
    paper's Table II defines MV; a mean of per-batch MV would not be it)."""
    return {**means, **scores_from_means(means)}


def _diverged(run: RunState, err: NonFinite) -> RunError:
    """The one-line error of a diverged run: its folder, the epoch under way (1-based; the
    history holds the finished ones) and what was not finite."""
    when = f"epoch {len(run.history) + 1}" if run.untrained_score is not None else "the untrained network"
    return RunError(f"{run.spec.paths.out_dir}: {when}: {err}")


def finite_losses(model: torch.nn.Module, out: dict, batch: dict, de_factor: float,
                  split: str = "") -> dict[str, torch.Tensor]:
    """The model's task losses (section III-B; the DE loss times ``de_factor``), each finite, else
    :class:`NonFinite` naming it (``non-finite <split> <task> loss (<value>)``). torch's BCE refuses a
    nan input ("should be between 0 and 1") before any loss exists: that is a nan loss too, of the
    first task whose output is not finite (Chen et al.'s internal reconstructions: its task)."""
    prefix = f"{split} " if split else ""
    try:
        losses = scale_de_loss(model.compute_losses(out, batch), de_factor)
    except RuntimeError as err:
        if "between 0 and 1" not in str(err):
            raise
        bad = [t for t, v in out.items() if not torch.isfinite(v).all()] or ["/".join(model.tasks)]
        raise NonFinite(f"non-finite {prefix}{bad[0]} loss (nan)") from None
    if not bool(torch.isfinite(torch.stack([v.detach().double() for v in losses.values()])).all()):
        task, value = next((t, v.item()) for t, v in losses.items() if not math.isfinite(v.item()))
        raise NonFinite(f"non-finite {prefix}{task} loss ({value})")
    return losses


class _Mean:
    """Running weighted means of scalar dicts."""

    def __init__(self) -> None:
        self.sums: dict[str, float] = {}
        self.n = 0.0

    def add(self, values: dict[str, Any], weight: float) -> None:
        for k, v in values.items():
            self.sums[k] = self.sums.get(k, 0.0) + float(v) * weight
        self.n += weight

    def mean(self) -> dict[str, float]:
        return {k: v / max(self.n, 1e-12) for k, v in self.sums.items()}


def evaluate_split(model: torch.nn.Module, loader, device: torch.device, spec: dict, dtype: torch.dtype,
                   de_factor: float = 1.0) -> dict[str, float]:
    """Mean per-frame metrics (and losses, the DE loss times ``de_factor``) of ``model`` over a
    loader, in eval mode."""
    model.eval()
    acc = _Mean()
    with torch.no_grad():
        for batch in loader:
            batch = to_device(batch, device, spec["num_seg_classes"], dtype=dtype)
            out = model(batch)
            losses = finite_losses(model, out, batch, de_factor, "validation")
            n = next(iter(batch.values())).shape[0]
            values = {f"loss_{k}": v.item() for k, v in losses.items()}
            values.update({k: float(v) for k, v in
                           compute_metrics(out, batch, argmax_tasks=model.argmax_tasks).items()})
            acc.add(values, n)
    return split_scores(acc.mean())


def validate(run: RunState) -> dict[str, float]:
    """The validation split's mean losses and metrics over every process's frames; a non-finite
    loss or selection score stops the run (:class:`RunError`)."""
    spec = run.spec
    try:
        means = evaluate_split(run.model, run.val_loader, spec.device, {"num_seg_classes": spec.num_seg_classes},
                               spec.dtype, run.de_factor)
    except NonFinite as err:
        raise _diverged(run, err) from None
    means = ddp.average_scalars(means, spec.dist, len(run.val_loader))
    score = selection_score(split_scores(means))
    if not math.isfinite(score):
        raise _diverged(run, NonFinite(f"non-finite validation score ({score})"))
    return means


def _step_taken(scaler: torch.amp.GradScaler, scale_before: float) -> bool:
    """Whether the optimiser step just taken went through: always, unless a float16 GradScaler
    found an inf or nan among the (rank-averaged) gradients, skipped it and lowered its scale.
    Reading the scale is a device-to-host copy: fp16 runs pay it, fp32 and bf16 do not."""
    return not scaler.is_enabled() or scaler.get_scale() >= scale_before


def train_step(run: RunState, batch: dict, step: int, n_steps: int) -> tuple[dict[str, float], int]:
    """One optimiser step on ``batch`` (the weighting's protocol: ``before_backward``, its
    ``backward``, the data-parallel gradient mean, the optimiser step, then ``after_backward``, which
    commits new loss weights only with a step the GradScaler took); returns the step's losses and
    metrics and the number of frames.

    Data-parallel order: the gradients are averaged before they are unscaled, so an inf on one
    rank skips the step on every rank alike; the loss weights are averaged only when they changed
    since they were last averaged (at a step or at an epoch's end, DWA's: a weighting replaces ``w``
    when it changes it, never edits it in place, so an identity test tells)."""
    spec, weighting, scaler = run.spec, run.weighting, run.scaler
    batch = to_device(batch, spec.device, spec.num_seg_classes, dtype=spec.dtype)
    run.optimizer.zero_grad(set_to_none=True)
    if spec.params.train.channels_last:
        batch = batch_to_channels_last(batch)
    with autocast_context(spec.device, run.precision):  # the forward only: losses in float32 (BCE clamps)
        out = float_outputs(run.forward(batch))
    losses = finite_losses(run.model, out, batch, run.de_factor)  # before any update: last.pt stays good
    scale_before = scaler.get_scale() if scaler.is_enabled() else 1.0
    weighting.grad_scale = scale_before
    weighting.before_backward(step, n_steps, losses, run.model)
    total = weighting.backward(losses, run.model, scaler.scale)     # with the step's weights w(t)
    if not math.isfinite(total.item()):  # finite losses, non-finite weights (a diverged weighting)
        raise NonFinite(f"non-finite total loss ({total.item()})")
    ddp.average_gradients(list(run.model.parameters()), spec.dist)  # still scaled: an inf reaches every rank
    scaler.unscale_(run.optimizer)
    scaler.step(run.optimizer)
    scaler.update()
    weighting.after_backward(taken=_step_taken(scaler, scale_before))  # w(t+1), if the step updated them
    if spec.dist.enabled and weighting.w is not run.synced_w:  # changed by a rank's own batch: agree
        weighting.set_weights(ddp.average_tensor(weighting.w, spec.dist))
        run.synced_w = weighting.w
    with torch.no_grad():
        values = {f"loss_{k}": v.item() for k, v in losses.items()}
        values["loss_total"] = total.item()
        values.update({k: float(v) for k, v in
                       compute_metrics(out, batch, argmax_tasks=run.model.argmax_tasks).items()})
    return values, next(iter(batch.values())).shape[0]


def train_epoch(run: RunState, epoch: int) -> dict[str, float]:
    """Every training step of ``epoch`` at the run's current lr; the epoch's mean losses and
    metrics over every process's frames."""
    spec = run.spec
    for group in run.optimizer.param_groups:
        group["lr"] = run.lr
    set_epoch(run.train_loader, epoch, spec.seed)
    run.model.train()
    acc, n_steps = _Mean(), len(run.train_loader)
    # the bar never touches the loader: a second iter() of a persistent-worker loader would
    # draw another shuffling order, so the worker count would change the result
    bar = tqdm(total=n_steps, desc=f"{spec.dataset_id}/{spec.model_id} epoch {epoch + 1}/{run.max_epochs}",
               disable=not (spec.dist.is_main and spec.progress), leave=False)
    for step, batch in enumerate(run.train_loader):
        try:
            values, frames = train_step(run, batch, step, n_steps)
        except NonFinite as err:
            bar.close()
            raise _diverged(run, err) from None
        acc.add(values, frames)
        bar.set_postfix(loss=f"{values['loss_total']:.3f}", refresh=False)
        bar.update()
    bar.close()
    return split_scores(ddp.average_scalars(acc.mean(), spec.dist, acc.n))
