"""One epoch of paper section IV-D: the training steps (with the loss weighting's step protocol of
section III-C, :mod:`compact_perception.learning.weighting`) and the validation pass, each averaged over
every process's frames.

The steps keep their losses and metrics on the device (:class:`EpochSums`) and the host reads
them once per epoch, so a GPU is never left waiting for the host inside an epoch.

A run that diverges stops: a training loss that is not finite stops it at the epoch's last step,
before that step's update (the epoch's loss sums are read there), a non-finite validation loss or
score before the epoch is recorded or saved, with one line naming the run folder, the epoch and
the loss (:class:`RunError`); ``last.pt`` stays at the last finished epoch.
"""
from __future__ import annotations

import math
from typing import Callable

import torch
from tqdm.auto import tqdm

from . import distributed as ddp
from ...core.errors import NonFinite, RunError
from ...data.loader import set_epoch, to_device
from ..losses import scale_de_loss
from ..metrics import metric_tensors, scores_from_means, total_metric_partial
from .precision import autocast_context, batch_to_channels_last, float_outputs
from .state import RunState

__all__ = ["EpochSums", "NonFinite", "epoch_means", "evaluate_split", "prepare_batch", "selection_score", "split_scores",
           "step_on_device", "task_losses", "train_epoch", "train_step", "validate"]


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
    return RunError(f"{run.spec.planned.paths.run_dir}: {when}: {err}")


def task_losses(model: torch.nn.Module, out: dict, batch: dict, de_factor: float,
                split: str = "") -> dict[str, torch.Tensor]:
    """The model's task losses (section III-B; the DE loss times ``de_factor``), unchecked: their
    finiteness is read once per epoch (:meth:`EpochSums.watch`, :meth:`EpochSums.raise_non_finite`). torch's BCE
    refuses a nan input ("should be between 0 and 1") before any loss exists: that is a nan loss at
    once (:class:`NonFinite`), of the first task whose output is not finite (Chen et al.'s internal
    reconstructions: its task)."""
    prefix = f"{split} " if split else ""
    try:
        return scale_de_loss(model.compute_losses(out, batch), de_factor)
    except RuntimeError as err:
        if "between 0 and 1" not in str(err):
            raise
        bad = [t for t, v in out.items() if not torch.isfinite(v).all()] or ["/".join(model.tasks)]
        raise NonFinite(f"non-finite {prefix}{bad[0]} loss (nan)") from None


class EpochSums:
    """Frame-weighted sums of per-step scalars (losses, metrics), kept on the device in float64
    and read by the host once (:meth:`means`), and the first non-finite value of the watched ones
    (the losses: :meth:`watch`, :meth:`raise_non_finite`).

    Each sum is the same IEEE arithmetic, in the same order, as a Python float accumulation of the
    values read step by step (``sum = sum + float(v) * frames``, from 0.0): two separate ops, a
    cast to float64 being exact, so a CPU run's means are the bytes they were when every step read
    its values. The divergence check reads, at the epoch's last step, the first step at which a
    watched value was not finite and that value: the same verdict and message as a check of every
    step (the earliest step's first non-finite loss in task order, then the total), one read."""

    def __init__(self) -> None:
        self.sums: dict[str, torch.Tensor] = {}
        self.n = 0.0
        self._first: dict[tuple[str, ...], tuple[torch.Tensor, torch.Tensor]] = {}  # keys -> (step, value)

    def add(self, values: dict[str, torch.Tensor], frames: int) -> None:
        """``sum_k += v * frames`` for every value (a 0-d tensor, on the device)."""
        for k, v in values.items():
            term = v.detach().to(torch.float64) * frames
            prev = self.sums.get(k)
            if prev is None:
                self.sums[k] = torch.zeros((), dtype=torch.float64, device=term.device) + term
            else:  # in place: a captured step (.capture) adds into the tensors it was captured with
                prev.add_(term)

    def watch(self, values: dict[str, torch.Tensor], step: int | torch.Tensor) -> None:
        """Record, without a host read, the step at which each of ``values`` was first not finite
        and that value (float64: the step index and a float32's value are exact). ``step``: the
        index, or a 0-d float64 tensor holding it (a captured step's, set before each replay)."""
        keys = tuple(values)
        v = torch.stack([x.detach().to(torch.float64) for x in values.values()])
        first = self._first.get(keys)
        if first is None:
            first = (torch.full_like(v, math.inf), torch.zeros_like(v))
            self._first[keys] = first
        at, value = first
        new = ~torch.isfinite(v) & torch.isinf(at)
        mark = step if isinstance(step, torch.Tensor) else float(step)
        value.copy_(torch.where(new, v, value))  # in place, as add()
        at.copy_(torch.where(new, mark, at))

    def raise_non_finite(self, what: Callable[[str], str]) -> None:
        """:class:`NonFinite` ``non-finite <what(key)> (<value>)`` for the watched value that was
        first not finite (the earliest step; at one step the first key watched), if any (one read)."""
        if not self._first:
            return
        keys = [k for group in self._first for k in group]
        flat = torch.cat([torch.cat([at, value]) for at, value in self._first.values()]).tolist()
        steps, values, pos = [], [], 0
        for group in self._first:
            n = len(group)
            steps += flat[pos:pos + n]
            values += flat[pos + n:pos + 2 * n]
            pos += 2 * n
        bad = [(at, i) for i, at in enumerate(steps) if math.isfinite(at)]
        if bad:
            _, i = min(bad)
            raise NonFinite(f"non-finite {what(keys[i])} ({values[i]})")

    def means(self, extra: torch.Tensor | None = None) -> tuple[dict[str, float], list[float]]:
        """The means ``sum / frames`` (Python floats), and ``extra``'s values, read in one transfer."""
        keys = list(self.sums)
        parts = [torch.stack([self.sums[k] for k in keys])] if keys else []
        if extra is not None:
            parts.append(extra.detach().to(device=parts[0].device if parts else extra.device,
                                           dtype=torch.float64).reshape(-1))
        flat = torch.cat(parts).tolist() if parts else []
        return {k: v / max(self.n, 1e-12) for k, v in zip(keys, flat)}, flat[len(keys):]


def _loss_keys(losses: dict) -> list[str]:
    return [f"loss_{k}" for k in losses]


def _loss_name(key: str) -> str:
    """``loss_de`` -> ``de loss``; ``loss_total`` -> ``total loss``."""
    return f"{key[len('loss_'):]} loss"


def evaluate_split(model: torch.nn.Module, loader, device: torch.device, spec: dict, dtype: torch.dtype,
                   de_factor: float = 1.0) -> dict[str, float]:
    """Mean per-frame metrics (and losses, the DE loss times ``de_factor``) of ``model`` over a
    loader, in eval mode; summed on the device and read once, after the last batch. A loss whose
    sum is not finite is :class:`NonFinite` (``non-finite validation <task> loss (<sum>)``)."""
    model.eval()
    sums = EpochSums()
    with torch.no_grad():
        for i, batch in enumerate(loader):
            batch = to_device(batch, device, spec["num_seg_classes"], dtype=dtype)
            out = model(batch)
            losses = task_losses(model, out, batch, de_factor, "validation")
            n = next(iter(batch.values())).shape[0]
            values = dict(zip(_loss_keys(losses), losses.values()))
            sums.add(values, n)
            sums.watch(values, i)
            sums.add(metric_tensors(out, batch, argmax_tasks=model.argmax_tasks), n)
            sums.n += n
    sums.raise_non_finite(lambda k: f"validation {_loss_name(k)}")
    return split_scores(sums.means()[0])


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


def _epoch_sums(run: RunState, step: int) -> EpochSums:
    """The running epoch's sums: new at its first step."""
    if step == 0 or run.epoch_sums is None:
        run.epoch_sums = EpochSums()
    return run.epoch_sums


def prepare_batch(run: RunState, batch: dict) -> dict:
    """A collated batch as the network takes it: on the run's device, expanded
    (:func:`~compact_perception.data.loader.to_device`), in the memory format of ``train.channels_last``
    (``true``: inputs and targets; ``inputs``: the inputs only)."""
    spec = run.spec
    batch = to_device(batch, spec.device, spec.num_seg_classes, dtype=spec.dtype)
    layout = spec.params.train.channels_last
    if layout:
        batch = batch_to_channels_last(batch, inputs_only=layout == "inputs")
    return batch


def train_step(run: RunState, batch: dict, step: int, n_steps: int) -> tuple[dict[str, torch.Tensor], int]:
    """One optimiser step on ``batch`` (the weighting's protocol: ``before_backward``, its
    ``backward``, the data-parallel gradient mean, the optimiser step, then ``after_backward``, which
    commits new loss weights only with a step the GradScaler took); adds the step's losses and
    metrics to the epoch's sums (``run.epoch_sums``, restarted at step 0) and returns them (0-d
    tensors on the device) with the number of frames.

    No value goes from the device to the host in a step but the epoch's last (and a float16
    GradScaler's own reads): the divergence check reads, at the epoch's last step, before that
    step's weighting update and optimiser step, the first non-finite loss of the epoch and raises
    :class:`NonFinite` naming it as a check of every step would have (the earliest step's first
    task in order, with its value; then the total loss, non-finite with finite losses: a diverged
    weighting). The run then stops before the epoch is recorded: ``last.pt`` stays at the last
    finished epoch.

    Data-parallel order: the gradients are averaged before they are unscaled, so an inf on one
    rank skips the step on every rank alike; the loss weights are averaged only when a step changed
    them since they were last averaged (a weighting replaces ``w`` when it changes it, never edits it
    in place, so an identity test tells). Weights set at an epoch's end (DWA's) come from sums over
    the ranks (the weighting's ``ranks``): the same on every rank from the next epoch's first step."""
    batch = prepare_batch(run, batch)
    run.optimizer.zero_grad(set_to_none=True)
    values = step_on_device(run, batch, step, n_steps)
    frames = next(iter(batch.values())).shape[0]
    run.epoch_sums.n += frames
    return values, frames


def step_on_device(run: RunState, batch: dict, step: int, n_steps: int, *, mark: torch.Tensor | None = None,
                   autocast_cache: bool = True) -> dict[str, torch.Tensor]:
    """The device work of :func:`train_step` on a prepared batch (:func:`prepare_batch`), the
    gradients already cleared: forward, losses, the weighting, backward, the optimiser step, the
    metrics, each added to the epoch's sums (their frame count, ``sums.n``, is the caller's to add).
    A captured step (:mod:`.capture`) runs it on fixed buffers: ``mark``, the step index as a
    device tensor, and no autocast weight cache (a captured graph cannot keep one)."""
    spec, weighting, scaler = run.spec, run.weighting, run.scaler
    last = step == n_steps - 1
    frames = next(iter(batch.values())).shape[0]
    with autocast_context(spec.device, run.precision, cache=autocast_cache):  # the forward only: losses in float32
        out = float_outputs(run.forward(batch))
    losses = task_losses(run.model, out, batch, run.de_factor)
    sums, loss_keys = _epoch_sums(run, step), _loss_keys(losses)
    at = step if mark is None else mark
    values = {k: v.detach() for k, v in zip(loss_keys, losses.values())}
    sums.add(values, frames)
    sums.watch(values, at)
    if last:  # before any update of this step: last.pt stays good
        sums.raise_non_finite(_loss_name)
    scale_before = scaler.get_scale() if scaler.is_enabled() else 1.0
    weighting.grad_scale = scale_before
    weighting.before_backward(step, n_steps, losses, run.model)
    total = weighting.backward(losses, run.model, scaler.scale)     # with the step's weights w(t)
    values["loss_total"] = total.detach()
    sums.add({"loss_total": values["loss_total"]}, frames)
    sums.watch({"loss_total": values["loss_total"]}, at)
    if last:  # finite losses, non-finite weights (a diverged weighting)
        sums.raise_non_finite(_loss_name)
    ddp.average_gradients(list(run.model.parameters()), spec.dist)  # still scaled: an inf reaches every rank
    scaler.unscale_(run.optimizer)
    scaler.step(run.optimizer)
    scaler.update()
    weighting.after_backward(taken=_step_taken(scaler, scale_before))  # w(t+1), if the step updated them
    if spec.dist.enabled and weighting.w is not run.synced_w:  # changed by a rank's own batch: agree
        weighting.set_weights(ddp.average_tensor(weighting.w, spec.dist))
        run.synced_w = weighting.w
    with torch.no_grad():
        metrics = metric_tensors(out, batch, argmax_tasks=run.model.argmax_tasks)
    sums.add(metrics, frames)
    values.update(metrics)
    return values


def epoch_means(run: RunState) -> dict[str, float]:
    """The epoch's mean losses and metrics over this process's frames, read with the loss weights
    in one transfer; weights that are not finite (a weighting that diverged on finite losses) are
    :class:`NonFinite`."""
    weighting = run.weighting
    means, w = (run.epoch_sums or EpochSums()).means(extra=weighting.w)
    if not all(math.isfinite(x) for x in w):
        raise NonFinite(f"non-finite {weighting.key} loss weights ({[round(x, 6) for x in w]})")
    return means


def train_epoch(run: RunState, epoch: int) -> dict[str, float]:
    """Every training step of ``epoch`` at the run's current lr; the epoch's mean losses and
    metrics over every process's frames, read from the device once, after its last step."""
    spec = run.spec
    for group in run.optimizer.param_groups:
        group["lr"] = run.lr
    set_epoch(run.train_loader, epoch, spec.rng_seed)
    run.model.train()
    n_steps = len(run.train_loader)
    # the bar never touches the loader: a second iter() of a persistent-worker loader would
    # draw another shuffling order, so the worker count would change the result
    bar = tqdm(total=n_steps, desc=f"{spec.planned.name} epoch {epoch + 1}/{spec.planned.max_epochs}",
               disable=not (spec.dist.is_main and spec.progress), leave=False)
    try:
        step_fn = run.captured or train_step  # a step captured as a CUDA graph (.capture), where it is
        for step, batch in enumerate(run.train_loader):
            step_fn(run, batch, step, n_steps)
            bar.update()
        means = epoch_means(run)
    except NonFinite as err:
        raise _diverged(run, err) from None
    finally:
        bar.close()
    n = run.epoch_sums.n if run.epoch_sums is not None else 0.0
    # TM and MV are recomputed from the means (eq. 6-7); their keys keep the places they have in a record
    return split_scores(ddp.average_scalars(split_scores(means), spec.dist, n))
