"""The training loop of paper section IV-D with the loss weighting of section III-C.

One run = one (dataset, model) pair. Per epoch it logs every task loss and metric (train
and val), the learning rates and the loss weights through dvclive (``dvcyaml=False``),
keeps the best-on-validation checkpoint, halves the lr on a validation-TM plateau, stops
early, and saves a resumable checkpoint after every finished epoch. A killed run started
again with the same configuration continues from its last finished epoch.

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
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from . import distributed as ddp
from . import io
from .config import ModelRecipe, Params
from .data import make_loader, set_epoch, to_device
from .metrics import compute_metrics
from .models import build_model
from .schedule import EarlyStop, Plateau
from .weighting import build_weighting

log = logging.getLogger(__name__)

#: Metric keys that enter the total metric TM (eq. 6); lower-is-better terms.
IOU_KEYS = ("iou_ss", "iou_ls", "iou_bevp")


def selection_score(metrics: dict[str, float]) -> float:
    """Validation score used for the schedule, early stopping and the best checkpoint.

    It is the total metric TM (eq. 6) over the tasks the model performs: equal to TM for
    the compact model, and to the model's own share of TM for a baseline.
    """
    score = metrics.get("mae_de", 0.0)
    for key in IOU_KEYS:
        if key in metrics:
            score += 1.0 - metrics[key]
    return float(score)


def resolve_device(pref: str) -> torch.device:
    if pref == "cuda" or (pref == "auto" and torch.cuda.is_available()):
        if not torch.cuda.is_available():
            raise RuntimeError("train.device is 'cuda' but no CUDA device is available")
        return torch.device("cuda")
    return torch.device("cpu")


def run_seed(params: Params, dataset_id: str, model_id: str) -> int:
    """Seed of one run, derived from ``params.seed`` and the run's ids (stable across runs)."""
    return (params.seed * 1_000_003 + zlib.crc32(f"{dataset_id}/{model_id}".encode())) % (2**31)


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


@dataclass
class RunConfig:
    """Everything that decides a run's result (its hash gates resuming)."""

    dataset_id: str
    model_id: str
    recipe: ModelRecipe
    batch_size: int
    max_epochs: int
    plateau_patience: int
    plateau_factor: float
    early_stop_patience: int
    seed: int
    cache_hash: str
    world_size: int

    def digest(self) -> str:
        blob = json.dumps(
            {k: (v.model_dump() if hasattr(v, "model_dump") else v) for k, v in self.__dict__.items()},
            sort_keys=True,
        )
        return hashlib.sha256(blob.encode()).hexdigest()[:16]


def make_optimizer(recipe: ModelRecipe, parameters) -> torch.optim.Optimizer:
    """SGD with momentum (section IV-D) or Adam (the baselines' recipes)."""
    if recipe.optimizer == "sgd":
        return torch.optim.SGD(parameters, lr=recipe.lr, momentum=recipe.momentum, weight_decay=recipe.weight_decay)
    return torch.optim.Adam(parameters, lr=recipe.lr, weight_decay=recipe.weight_decay)


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


def evaluate_split(model: torch.nn.Module, loader, device: torch.device, spec: dict, dtype: torch.dtype) -> dict[str, float]:
    """Mean per-frame metrics (and losses) of ``model`` over a loader, in eval mode."""
    model.eval()
    acc = _Mean()
    with torch.no_grad():
        for batch in loader:
            batch = to_device(batch, device, spec["num_seg_classes"], dtype=dtype)
            out = model(batch)
            losses = model.compute_losses(out, batch)
            n = next(iter(batch.values())).shape[0]
            values = {f"loss_{k}": v.item() for k, v in losses.items()}
            values.update({k: float(v) for k, v in compute_metrics(out, batch).items()})
            acc.add(values, n)
    return acc.mean()


def train_run(
    params: Params,
    dataset_id: str,
    model_id: str,
    cache_dir: Path,
    out_dir: Path,
    *,
    stop_after_epochs: int | None = None,
    dtype: torch.dtype = torch.float32,
) -> dict:
    """Train ``model_id`` on ``dataset_id`` from ``cache_dir`` into ``out_dir``.

    ``stop_after_epochs`` ends the process after that many epochs of this call without
    writing the summary (it simulates an interruption, for tests).
    """
    from dvclive import Live

    cache_dir, out_dir = Path(cache_dir), Path(out_dir)
    tp = params.train
    recipe = tp.models[model_id]
    device = resolve_device(tp.device)
    dist_ = ddp.init_from_env(device.type)
    if dist_.enabled and device.type == "cuda":
        device = torch.device("cuda", dist_.local_rank)
    seed = run_seed(params, dataset_id, model_id)
    seed_everything(seed)
    torch.use_deterministic_algorithms(True, warn_only=True)

    meta = json.loads((cache_dir / "meta.json").read_text())
    spec = {"num_seg_classes": len(meta["seg_classes"])}
    model = build_model(model_id, dataset_id).to(device=device, dtype=dtype)
    lidar_channels = getattr(model, "lidar_channels", 15)
    weighting = build_weighting(recipe, model.tasks, model, plateau_patience=tp.plateau_patience,
                                plateau_factor=tp.plateau_factor)
    optimizer = make_optimizer(recipe, model.parameters())
    max_epochs = (recipe.max_epochs or tp.max_epochs).at(params.scale)
    plateau = Plateau(tp.plateau_patience, tp.plateau_factor, recipe.lr_min)
    stopper = EarlyStop(tp.early_stop_patience)
    use_amp = tp.amp and device.type == "cuda"
    scaler = torch.amp.GradScaler("cuda", enabled=use_amp)

    cfg = RunConfig(
        dataset_id, model_id, recipe, tp.batch_size, max_epochs, tp.plateau_patience, tp.plateau_factor,
        tp.early_stop_patience, seed, cache_fingerprint(cache_dir), dist_.world_size,
    )
    digest = cfg.digest()
    per_rank_batch = max(1, tp.batch_size // dist_.world_size)

    # ---------------------------------------------------------------- resume or start
    start_epoch, history, best_score, best_epoch, lr = 0, [], math.inf, -1, recipe.lr
    untrained_score = None
    last_path, best_path, summary_path = out_dir / "last.pt", out_dir / "best.pt", out_dir / "summary.json"
    state = None
    if last_path.exists():
        state = torch.load(last_path, map_location=device, weights_only=False)
        if state.get("digest") != digest:
            log.info("%s: existing checkpoint has another configuration; starting afresh", out_dir)
            state = None
    if state is None and dist_.is_main:
        for stale in (last_path, best_path, summary_path):
            stale.unlink(missing_ok=True)
        import shutil

        shutil.rmtree(out_dir / "live", ignore_errors=True)
    ddp.barrier(dist_)
    if state is not None:
        if state.get("finished") and summary_path.exists():
            log.info("%s: already complete for this configuration", out_dir)
            return json.loads(summary_path.read_text())
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        weighting.load_state_dict(state["weighting"])
        plateau.load_state_dict(state["plateau"])
        stopper.load_state_dict(state["stopper"])
        start_epoch, history = state["epoch"] + 1, state["history"]
        best_score, best_epoch, lr = state["best_score"], state["best_epoch"], state["lr"]
        untrained_score = state.get("untrained_score")
        torch.set_rng_state(state["torch_rng"])
        log.info("%s: resuming after epoch %d", out_dir, state["epoch"])

    live = Live(str(out_dir / "live"), dvcyaml=False, save_dvc_exp=False, resume=start_epoch > 0) if dist_.is_main else None
    val_loader = make_loader(cache_dir, "val", lidar_channels, per_rank_batch, shuffle=False, seed=seed,
                             num_workers=tp.num_workers, drop_last=False, distributed=dist_.enabled)
    if untrained_score is None:  # the reference that training must beat (Kaiming-initialised network)
        untrained_score = selection_score(
            ddp.average_scalars(evaluate_split(model, val_loader, device, spec, dtype), dist_, len(val_loader)))
        log.info("%s/%s untrained val score %.4f", dataset_id, model_id, untrained_score)
    train_loader = make_loader(cache_dir, "train", lidar_channels, per_rank_batch, shuffle=True, seed=seed,
                               num_workers=tp.num_workers, drop_last=True, distributed=dist_.enabled)
    n_steps = len(train_loader)
    if n_steps == 0:
        raise ValueError(f"{cache_dir}/train: fewer frames than one batch of {per_rank_batch}")
    t_start = time.perf_counter()
    elapsed_before = state["elapsed_s"] if state is not None else 0.0
    stop = bool(state and state.get("stopped_early"))
    epochs_this_call = 0
    epoch = start_epoch - 1
    for epoch in range(start_epoch, max_epochs):
        if stop:
            break
        _set_lr(optimizer, lr)
        set_epoch(train_loader, epoch, seed)
        model.train()
        acc = _Mean()
        bar = tqdm(train_loader, desc=f"{dataset_id}/{model_id} epoch {epoch + 1}/{max_epochs}",
                   disable=not dist_.is_main, leave=False)
        for step, batch in enumerate(bar):
            batch = to_device(batch, device, spec["num_seg_classes"], dtype=dtype)
            optimizer.zero_grad(set_to_none=True)
            with torch.autocast("cuda", dtype=torch.float16) if use_amp else nullcontext():
                out = model(batch)
                losses = model.compute_losses(out, batch)
            losses = {k: v.float() if use_amp else v for k, v in losses.items()}
            weighting.before_backward(step, n_steps, losses, model)
            if dist_.enabled:  # each rank's update saw its own batch: agree on the mean weights
                weighting.set_weights(ddp.average_tensor(weighting.w, dist_))
            total = weighting.total(losses)
            scaler.scale(total).backward()
            if use_amp:
                scaler.unscale_(optimizer)
            ddp.average_gradients(list(model.parameters()), dist_)
            scaler.step(optimizer)
            scaler.update()
            with torch.no_grad():
                values = {f"loss_{k}": v.item() for k, v in losses.items()}
                values["loss_total"] = total.item()
                values.update({k: float(v) for k, v in compute_metrics(out, batch).items()})
            acc.add(values, next(iter(batch.values())).shape[0])
            bar.set_postfix(loss=f"{values['loss_total']:.3f}")
        train_m = ddp.average_scalars(acc.mean(), dist_, acc.n)
        val_m = ddp.average_scalars(evaluate_split(model, val_loader, device, spec, dtype), dist_, len(val_loader))
        score = selection_score(val_m)
        improved, lr = plateau.step(score, lr)
        weighting.on_epoch_end(improved)
        stop = stopper.step(score)
        if improved:
            best_score, best_epoch = score, epoch
        record = {"epoch": epoch, "lr": optimizer.param_groups[0]["lr"], "val_score": score,
                  **{f"train/{k}": v for k, v in train_m.items()}, **{f"val/{k}": v for k, v in val_m.items()},
                  **weighting.log_values()}
        history.append(record)
        log.info("%s/%s epoch %d: val score %.4f%s", dataset_id, model_id, epoch + 1, score,
                 " (best)" if improved else "")
        if dist_.is_main:
            live.step = epoch
            for k, v in record.items():
                if k != "epoch":
                    live.log_metric(k, v)
            live.next_step()
            if improved:
                with io.atomic_path(best_path) as tmp:
                    torch.save({"model": model.state_dict(), "epoch": epoch, "score": score}, tmp)
            with io.atomic_path(last_path) as tmp:
                torch.save({
                    "digest": digest, "epoch": epoch, "model": model.state_dict(),
                    "optimizer": optimizer.state_dict(), "weighting": weighting.state_dict(),
                    "plateau": plateau.state_dict(), "stopper": stopper.state_dict(), "history": history,
                    "best_score": best_score, "best_epoch": best_epoch, "lr": lr,
                    "torch_rng": torch.get_rng_state(), "stopped_early": stop,
                    "elapsed_s": elapsed_before + time.perf_counter() - t_start, "finished": False,
                    "untrained_score": untrained_score,
                }, tmp)
        ddp.barrier(dist_)
        epochs_this_call += 1
        if stop_after_epochs is not None and epochs_this_call >= stop_after_epochs and epoch + 1 < max_epochs:
            if live is not None:
                live.end()
            ddp.shutdown(dist_)
            raise InterruptedError(f"stopped after epoch {epoch + 1} (stop_after_epochs)")

    summary = {
        "dataset": dataset_id, "model": model_id, "best_epoch": best_epoch, "best_val_score": best_score,
        "untrained_val_score": untrained_score,
        "epochs_run": len(history), "max_epochs": max_epochs, "stopped_early": stop,
        "train_seconds": round(elapsed_before + time.perf_counter() - t_start, 2),
        "params": int(sum(p.numel() for p in model.parameters())), "world_size": dist_.world_size,
        "final_weights": {k: v for k, v in (history[-1] if history else {}).items() if k.startswith("w_")},
        "digest": digest,
    }
    if dist_.is_main:
        live.end()
        state = torch.load(last_path, map_location="cpu", weights_only=False)
        state["finished"] = True
        with io.atomic_path(last_path) as tmp:
            torch.save(state, tmp)
        io.write_json(summary_path, summary)
    ddp.barrier(dist_)
    ddp.shutdown(dist_)
    return summary
