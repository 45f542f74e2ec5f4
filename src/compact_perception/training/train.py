"""The training loop of paper section IV-D with the loss weighting of section III-C.

One run = one (dataset, model) pair. Per epoch it logs every task loss and metric (train
and val), the learning rates and the loss weights through dvclive (``dvcyaml=False``),
keeps the best-on-validation checkpoint, halves the lr on a validation-TM plateau, stops
early, and saves a resumable checkpoint after every finished epoch. A killed run started
again with the same code, params and data continues from its last finished epoch and ends
with the same bytes as an uninterrupted run; any other change starts it afresh (the
checkpoint's digest covers the source code, every ``train`` param of the run and the data).

Outputs (``out_dir``, a persistent DVC output):

- ``last.pt``      resumable state (model, optimiser, weighting, schedules, history)
- ``best.pt``      model weights at the best validation score
- ``live/``        dvclive logs (``live/plots/metrics/{train,val}/*.tsv``, ``lr``, ``w_*``)
- ``summary.json`` best epoch, scores, epochs run, wall time; written last (= run complete)
"""
from __future__ import annotations

import hashlib
import json
import logging
import math
import random
import time
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from . import distributed as ddp
from ..core import io
from ..core import catalog
from ..core.config import ModelRecipe, Params
from ..core.determinism import release_torch_pins, resolve_device, set_threads
from ..core.errors import RunError
from ..data import make_loader, set_epoch, to_device
from ..losses import de_loss_factor, scale_de_loss
from ..metrics import compute_metrics, scores_from_means, total_metric_partial
from ..models import build_model
from .precision import (autocast_context, batch_to_channels_last, float_outputs, make_grad_scaler, maybe_compile,
                        resolve_precision, to_channels_last)
from .provenance import source_fingerprint
from .schedule import EarlyStop, Plateau
from ..weighting import build_weighting, network_tasks, weighting_settings

log = logging.getLogger(__name__)



def selection_score(metrics: dict[str, float]) -> float:
    """Validation score used for the schedule, early stopping and the best checkpoint.

    It is the total metric TM (eq. 6) over the tasks the model performs: equal to TM for
    the compact model, and to the model's own share of TM for a baseline.
    """
    return total_metric_partial(metrics)


def _split_scores(means: dict[str, float]) -> dict[str, float]:
    """A split's mean scores with TM and MV recomputed from the four means (eq. 6-7, as the
    paper's Table II defines MV; a mean of per-batch MV would not be it)."""
    return {**means, **scores_from_means(means)}


def run_seed(params: Params, dataset_id: str, seed: int) -> int:
    """RNG seed of one run, derived from ``params.seed``, the dataset and the run's training seed
    ``seed`` (one of ``params.seeds``; not read here, so adding a seed reruns no other run). It
    does not depend on the model: at one seed every model of the same network starts from the same
    initial weights and sees the same batches (common random numbers), so the paired comparisons
    of the claims and the study compare training methods, not initialisations."""
    if seed < 0:
        raise RunError(f"seed: expected a non-negative training seed, got {seed}")
    return (params.seed * 1_000_003 + zlib.crc32(f"{dataset_id}/seed{seed}".encode())) % (2**31)


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % (2**32))
    torch.manual_seed(seed)


def cache_fingerprint(cache_dir: Path) -> str:
    """Content hash of the training and validation cache (decides whether to resume)."""
    h = hashlib.sha256()
    for path in sorted(p for p in Path(cache_dir).rglob("*") if p.is_file() and "test" not in p.parts):
        h.update(str(path.relative_to(cache_dir)).encode())
        with path.open("rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 22), b""):
                h.update(chunk)
    return h.hexdigest()


def run_digest(params: Params, dataset_id: str, model_id: str, seed: int, cache_hash: str,
               world_size: int, recipe: ModelRecipe | None = None) -> str:
    """Digest of everything that decides a run's result; it gates resuming and skipping.

    It covers the source code (:func:`~compact_perception.training.provenance.source_fingerprint`),
    the torch version, ``scale``, the run's seed, every ``train`` param except the recipes (the
    run's own merged recipe is covered whole) and the settings that cannot change a result
    (``num_workers``, ``device``), the training and validation data, and the number of processes.
    """
    train = params.train.model_dump(exclude={"models", "recipe", "num_workers", "device"})
    blob = json.dumps({
        "code": source_fingerprint(), "torch": torch.__version__, "scale": params.scale,
        "dataset": dataset_id, "model": model_id, "seed": seed, "train": train,
        "recipe": (recipe or params.train.models[model_id]).model_dump(), "data": cache_hash,
        "world_size": world_size,
    }, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def make_optimizer(recipe, parameters) -> torch.optim.Optimizer:
    """SGD with momentum (section IV-D) or Adam (the baselines' recipes).

    Adam runs torch's fused kernel (one pass over each tensor, CPU and CUDA): on the GradNorm
    SegNet's 118 M parameters it is about 5x faster per step than the default per-tensor loop
    (measured on a 2-core CPU),
    and it is elementwise, so its result does not depend on the thread count."""
    if recipe.optimizer == "sgd":
        return torch.optim.SGD(parameters, lr=recipe.lr, momentum=recipe.momentum, weight_decay=recipe.weight_decay)
    return torch.optim.Adam(parameters, lr=recipe.lr, betas=tuple(recipe.betas), eps=recipe.eps,
                            weight_decay=recipe.weight_decay, fused=True)


def _set_lr(opt: torch.optim.Optimizer, lr: float) -> None:
    for group in opt.param_groups:
        group["lr"] = lr


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
            losses = scale_de_loss(model.compute_losses(out, batch), de_factor)
            n = next(iter(batch.values())).shape[0]
            values = {f"loss_{k}": v.item() for k, v in losses.items()}
            values.update({k: float(v) for k, v in
                           compute_metrics(out, batch, argmax_tasks=model.argmax_tasks).items()})
            acc.add(values, n)
    return _split_scores(acc.mean())


def _save(obj: Any, path: Path, final: Path) -> None:
    """``torch.save`` whose write failures are :class:`OSError` naming the file. On a full disk
    torch raises ``RuntimeError: [enforce fail at inline_container.cc] unexpected pos``.

    It writes through an open file: given a path, torch names the archive's root folder after
    the file, and ``path`` is a random temporary name (:func:`io.atomic_path`), so the same
    checkpoint would get other bytes on every run."""
    try:
        with open(path, "wb") as f:
            torch.save(obj, f)
    except OSError as err:
        raise OSError(err.errno, err.strerror, str(final)) from None
    except RuntimeError as err:
        if "inline_container" not in str(err) and "PytorchStreamWriter" not in str(err):
            raise
        import errno
        import shutil

        free = shutil.disk_usage(Path(path).parent).free
        reason = "No space left on device" if free < (64 << 20) else f"write failed: {str(err).splitlines()[0]}"
        raise OSError(errno.ENOSPC if free < (64 << 20) else errno.EIO, reason, str(final)) from None


def _replay_live(live, history: list[dict]) -> None:
    """Write the logged epochs of ``history`` into a fresh dvclive folder (a resumed run's
    logs then hold exactly the epochs its checkpoint holds, no more, no fewer)."""
    for record in history:
        _log_epoch(live, record)


def _log_epoch(live, record: dict) -> None:
    live.step = record["epoch"]
    for k, v in record.items():
        if k != "epoch":
            live.log_metric(k, v)
    live.next_step()


def _export_best(model: torch.nn.Module, best_path: Path, onnx_path: Path, loader, device: torch.device,
                 spec: dict) -> dict:
    """Write the best checkpoint's network as ONNX (issue 15) and check it against PyTorch on one
    validation frame; returns the largest absolute output difference."""
    from ..export import export_onnx

    model.load_state_dict(torch.load(best_path, map_location=device, weights_only=False)["model"])
    batch = to_device(next(iter(loader)), device, spec["num_seg_classes"])
    one = {k: v[:1] for k, v in batch.items()}
    report = export_onnx(model, one, onnx_path)
    log.info("%s: ONNX max abs difference to PyTorch %.2e", onnx_path, report["max_abs_diff_all"])
    return {"file": onnx_path.name, "max_abs_diff": float(report["max_abs_diff_all"])}


def _check_inputs(params: Params, model_id: str, recipe: ModelRecipe, where: str, cache_dir: Path,
                  per_rank_batch: int) -> dict:
    """Everything a run needs, checked before anything is written; returns the cache meta.
    ``where``: the params key of ``recipe`` (for the messages)."""
    from ..core.cache import CacheError, read_meta, read_split

    compact = catalog.MODELS[model_id].group == "compact"
    if compact and recipe.de_loss is None:
        raise RunError(f"{where}.de_loss: required for a compact model (huber or smooth_l1)")
    if not compact and recipe.de_loss is not None:
        raise RunError(f"{where}.de_loss: only the compact models take it (a baseline keeps its own losses); "
                       "remove the key (set it to null where the recipe inherits it from train.recipe)")
    weighting_settings(recipe)
    meta = read_meta(cache_dir)
    n_train = len(read_split(cache_dir, "train", meta).frame_ids)
    n_val = len(read_split(cache_dir, "val", meta).frame_ids)
    if n_train < per_rank_batch:
        raise RunError(f"train.batch_size: {params.train.batch_size} needs at least {per_rank_batch} training "
                       f"frames per process, {cache_dir / 'train'} has {n_train}")
    if n_val == 0:
        raise CacheError(f"{cache_dir / 'val'}: the validation split is empty")
    return meta


def train_run(
    params: Params,
    dataset_id: str,
    model_id: str,
    seed: int,
    cache_dir: Path,
    out_dir: Path,
    *,
    recipe: ModelRecipe | None = None,
    recipe_key: str | None = None,
    stop_after_epochs: int | None = None,
    dtype: torch.dtype = torch.float32,
    export_onnx: bool = True,
) -> dict:
    """Train ``model_id`` on ``dataset_id`` with training seed ``seed`` (one of ``params.seeds``)
    from ``cache_dir`` into ``out_dir``. ``recipe`` (default ``train.models.<model_id>``) and
    ``recipe_key``, its params key for messages, let the study train one network with other recipes.

    ``export_onnx`` writes a compact network's best checkpoint as ``model.onnx`` too (issue 15);
    the study turns it off, its arms being comparisons, not deployable models.

    ``stop_after_epochs`` ends the process after that many epochs of this call without
    writing the summary (it simulates an interruption, for tests). A failure to write a
    checkpoint (a full disk) raises :class:`RunError`; a run that never saved an epoch then
    leaves nothing behind.
    """
    cache_dir, out_dir = Path(cache_dir), Path(out_dir)
    tp = params.train
    if recipe is None:
        recipe, recipe_key = tp.models[model_id], f"train.models.{model_id}"
    recipe_key = recipe_key or f"train.models.{model_id}"
    if tp.precision != "fp32":  # mixed precision wants the CPU's own (bf16/AMX) kernels: no pins, no bit promise
        release_torch_pins()
    device = resolve_device(tp.device)
    dist_ = ddp.init_from_env(device.type)
    if dist_.enabled and device.type == "cuda":
        device = torch.device("cuda", dist_.local_rank)
    per_rank_batch = max(1, tp.batch_size // dist_.world_size)
    meta = _check_inputs(params, model_id, recipe, recipe_key, cache_dir, per_rank_batch)
    set_threads(tp.num_threads)
    rng_seed = run_seed(params, dataset_id, seed)
    digest = run_digest(params, dataset_id, model_id, rng_seed, cache_fingerprint(cache_dir), dist_.world_size,
                        recipe)
    last_path, best_path, summary_path = out_dir / "last.pt", out_dir / "best.pt", out_dir / "summary.json"
    try:
        return _train(params, dataset_id, model_id, recipe, cache_dir, out_dir, meta, device, dist_, rng_seed, digest,
                      per_rank_batch, stop_after_epochs, dtype, export_onnx)
    except InterruptedError:  # stop_after_epochs (an OSError subclass): not a write failure
        raise
    except OSError as err:  # a full disk, a read-only folder: say which file, leave no half-run
        if dist_.is_main and not last_path.exists():
            import shutil

            shutil.rmtree(out_dir / "live", ignore_errors=True)
            for stale in (best_path, summary_path):
                stale.unlink(missing_ok=True)
        where = err.filename or out_dir
        raise RunError(f"{where}: could not write the run ({err.strerror or err})") from None


def _train(params: Params, dataset_id: str, model_id: str, recipe: ModelRecipe, cache_dir: Path, out_dir: Path,
           meta: dict,
           device: torch.device, dist_, seed: int, digest: str, per_rank_batch: int,
           stop_after_epochs: int | None, dtype: torch.dtype, export_onnx: bool) -> dict:
    from dvclive import Live

    tp = params.train
    seed_everything(seed)
    torch.use_deterministic_algorithms(True, warn_only=True)
    spec = {"num_seg_classes": len(meta["seg_classes"])}
    tasks = network_tasks(recipe, catalog.MODELS[model_id].tasks)  # one task for the study's single-task nets
    model = build_model(model_id, dataset_id, tasks).to(device=device, dtype=dtype)
    if tp.channels_last:
        model = to_channels_last(model)
    lidar_channels = catalog.MODELS[model_id].lidar_channels
    argmax_tasks = model.argmax_tasks  # softmax heads, scored by their arg-max map (metrics.scored_outputs)
    weighting = build_weighting(recipe, model.tasks, model, plateau_patience=tp.plateau_patience,
                                plateau_factor=tp.plateau_factor)
    optimizer = make_optimizer(recipe, model.parameters())
    max_epochs = (recipe.max_epochs or tp.max_epochs).at(params.scale)
    plateau = Plateau(tp.plateau_patience, tp.plateau_factor, recipe.lr_min, recipe.plateau_rule,
                      tp.plateau_threshold)
    de_factor = de_loss_factor(recipe.de_loss) if recipe.de_loss is not None else 1.0
    stopper = EarlyStop(tp.early_stop_patience)
    prec = resolve_precision(tp.precision, device)
    scaler = make_grad_scaler(device, prec)
    fwd = maybe_compile(model, tp.compile)

    # ---------------------------------------------------------------- resume or start
    start_epoch, history, best_score, best_epoch, lr = 0, [], math.inf, -1, recipe.lr
    untrained_score = None
    last_path, best_path, summary_path = out_dir / "last.pt", out_dir / "best.pt", out_dir / "summary.json"
    state = None
    if last_path.exists():
        try:
            state = torch.load(last_path, map_location=device, weights_only=False)
        except Exception as err:  # a checkpoint cut short by a kill: start afresh
            log.info("%s: unreadable checkpoint (%s); starting afresh", last_path, err)
            state = None
        if state is not None and state.get("digest") != digest:
            log.info("%s: the checkpoint is of other code, params or data; starting afresh", out_dir)
            state = None
    if state is not None and state.get("finished") and summary_path.exists():
        log.info("%s: already complete for this code, params and data", out_dir)
        ddp.shutdown(dist_)
        return json.loads(summary_path.read_text())
    if dist_.is_main:
        import shutil

        if state is None:
            for stale in (last_path, best_path, summary_path):
                stale.unlink(missing_ok=True)
        shutil.rmtree(out_dir / "live", ignore_errors=True)  # rebuilt from the checkpoint's history
    ddp.barrier(dist_)
    if state is not None:
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        weighting.load_state_dict(state["weighting"])
        plateau.load_state_dict(state["plateau"])
        stopper.load_state_dict(state["stopper"])
        start_epoch, history = state["epoch"] + 1, state["history"]
        best_score, best_epoch, lr = state["best_score"], state["best_epoch"], state["lr"]
        untrained_score = state.get("untrained_score")
        torch.set_rng_state(state["torch_rng"])
        log.info("%s: resuming after epoch %d", out_dir, state["epoch"] + 1)

    val_loader = make_loader(cache_dir, "val", lidar_channels, per_rank_batch, shuffle=False, seed=seed,
                             num_workers=tp.num_workers, drop_last=False, distributed=dist_.enabled)
    if untrained_score is None:  # the reference that training must beat (Kaiming-initialised network)
        untrained_score = selection_score(
            ddp.average_scalars(evaluate_split(model, val_loader, device, spec, dtype, de_factor), dist_,
                                len(val_loader)))
        log.info("%s/%s untrained val score %.4f", dataset_id, model_id, untrained_score)
    train_loader = make_loader(cache_dir, "train", lidar_channels, per_rank_batch, shuffle=True, seed=seed,
                               num_workers=tp.num_workers, drop_last=True, distributed=dist_.enabled)
    n_steps = len(train_loader)
    live = None
    if dist_.is_main:
        live = Live(str(out_dir / "live"), dvcyaml=False, save_dvc_exp=False)
        _replay_live(live, history)
    t_start = time.perf_counter()
    elapsed_before = state["elapsed_s"] if state is not None else 0.0
    stop = bool(state and state.get("stopped_early"))
    epochs_this_call = 0
    for epoch in range(start_epoch, max_epochs):
        if stop:
            break
        _set_lr(optimizer, lr)
        set_epoch(train_loader, epoch, seed)
        model.train()
        acc = _Mean()
        # the bar never touches the loader: a second iter() of a persistent-worker loader would
        # draw another shuffling order, so the worker count would change the result
        bar = tqdm(total=n_steps, desc=f"{dataset_id}/{model_id} epoch {epoch + 1}/{max_epochs}",
                   disable=not dist_.is_main, leave=False)
        for step, batch in enumerate(train_loader):
            batch = to_device(batch, device, spec["num_seg_classes"], dtype=dtype)
            optimizer.zero_grad(set_to_none=True)
            if tp.channels_last:
                batch = batch_to_channels_last(batch)
            with autocast_context(device, prec):  # the forward only: losses in float32 (BCE clamps)
                out = float_outputs(fwd(batch))
            losses = scale_de_loss(model.compute_losses(out, batch), de_factor)
            weighting.grad_scale = scaler.get_scale() if scaler.is_enabled() else 1.0
            weighting.before_backward(step, n_steps, losses, model)
            if dist_.enabled:  # each rank's update saw its own batch: agree on the mean weights
                weighting.set_weights(ddp.average_tensor(weighting.w, dist_))
            total = weighting.backward(losses, model, scaler.scale)
            scaler.unscale_(optimizer)
            ddp.average_gradients(list(model.parameters()), dist_)
            scaler.step(optimizer)
            scaler.update()
            with torch.no_grad():
                values = {f"loss_{k}": v.item() for k, v in losses.items()}
                values["loss_total"] = total.item()
                values.update({k: float(v) for k, v in
                               compute_metrics(out, batch, argmax_tasks=argmax_tasks).items()})
            acc.add(values, next(iter(batch.values())).shape[0])
            bar.set_postfix(loss=f"{values['loss_total']:.3f}", refresh=False)
            bar.update()
        bar.close()
        train_m = _split_scores(ddp.average_scalars(acc.mean(), dist_, acc.n))
        val_m = _split_scores(ddp.average_scalars(
            evaluate_split(model, val_loader, device, spec, dtype, de_factor), dist_, len(val_loader)))
        score = selection_score(val_m)
        plateau_improved, lr = plateau.step(score, lr)
        weighting.on_epoch_end(plateau_improved)
        stop = stopper.step(score)
        improved = score < best_score  # the best checkpoint: any drop (both plateau rules)
        if improved:
            best_score, best_epoch = score, epoch
        record = {"epoch": epoch, "lr": optimizer.param_groups[0]["lr"], "val_score": score,
                  **{f"train/{k}": v for k, v in train_m.items()}, **{f"val/{k}": v for k, v in val_m.items()},
                  **weighting.log_values()}
        history.append(record)
        log.info("%s/%s epoch %d: val score %.4f%s", dataset_id, model_id, epoch + 1, score,
                 " (best)" if improved else "")
        if dist_.is_main:  # the checkpoint first: the logs never hold an epoch it lacks
            if improved:
                with io.atomic_path(best_path) as tmp:
                    _save({"model": model.state_dict(), "tasks": list(model.tasks), "epoch": epoch, "score": score},
                          tmp, best_path)
            with io.atomic_path(last_path) as tmp:
                _save({
                    "digest": digest, "epoch": epoch, "model": model.state_dict(),
                    "optimizer": optimizer.state_dict(), "weighting": weighting.state_dict(),
                    "plateau": plateau.state_dict(), "stopper": stopper.state_dict(), "history": history,
                    "best_score": best_score, "best_epoch": best_epoch, "lr": lr,
                    "torch_rng": torch.get_rng_state(), "stopped_early": stop,
                    "elapsed_s": elapsed_before + time.perf_counter() - t_start, "finished": False,
                    "untrained_score": untrained_score,
                }, tmp, last_path)
            _log_epoch(live, record)
        ddp.barrier(dist_)
        epochs_this_call += 1
        if stop_after_epochs is not None and epochs_this_call >= stop_after_epochs and epoch + 1 < max_epochs:
            if live is not None:
                live.end()
            ddp.shutdown(dist_)
            raise InterruptedError(f"stopped after epoch {epoch + 1} (stop_after_epochs)")

    summary = {
        "dataset": dataset_id, "model": model_id, "rng_seed": seed, "best_epoch": best_epoch, "best_val_score": best_score,
        "untrained_val_score": untrained_score,
        "epochs_run": len(history), "max_epochs": max_epochs, "stopped_early": stop,
        "train_seconds": round(elapsed_before + time.perf_counter() - t_start, 2),
        "params": int(sum(p.numel() for p in model.parameters())), "world_size": dist_.world_size,
        "final_weights": {k: v for k, v in (history[-1] if history else {}).items() if k.startswith("w_")},
        "digest": digest,
    }
    if export_onnx and dist_.is_main and catalog.MODELS[model_id].group == "compact":  # deployable, beside its checkpoint
        summary["onnx"] = _export_best(model, best_path, out_dir / "model.onnx", val_loader, device, spec)
    if dist_.is_main:
        live.end()
        state = torch.load(last_path, map_location="cpu", weights_only=False)
        state["finished"] = True
        with io.atomic_path(last_path) as tmp:
            _save(state, tmp, last_path)
        io.write_json(summary_path, summary)
    ddp.barrier(dist_)
    ddp.shutdown(dist_)
    return summary
