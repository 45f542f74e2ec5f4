"""The training loop of paper section IV-D with the loss weighting of section III-C.

One run = one planned run (:class:`~compact_perception.learning.plan.PlannedRun`: a model or a study arm
at a seed on a dataset, with its recipe, epoch cap and paths), carried whole. Per epoch it logs
every task loss and metric (train and val), the learning rates and the loss weights through
dvclive (``dvcyaml=False``), keeps the best-on-validation checkpoint, halves the lr on a
validation-TM plateau, stops early, and saves a resumable checkpoint after every finished epoch.
A killed run started again with the same code, params and data continues from its last finished
epoch and ends with the same bytes as an uninterrupted run; any other change starts it afresh
(the checkpoint's digest covers the source code, every ``train`` param of the run and the data).

Outputs (the run's ``paths.run_dir``, a persistent DVC output):

- ``last.pt``      resumable state (model, optimiser, weighting, schedules, history)
- ``best.pt``      model weights at the best validation score
- ``live/``        dvclive logs (``live/plots/metrics/{train,val}/*.tsv``, ``lr``, ``w_*``)
- ``summary.json`` best epoch, scores, epochs run, wall time, the device and precision it ran on,
                   the SHA-256 of ``best.pt`` (``best_sha256``: evaluation checks it); written last
                   (= run complete)

:func:`train_run` checks its inputs, then runs these steps over one :class:`~.state.RunState`:

- ``_setup``       seed, network, weighting, optimiser, schedules, precision hooks
- ``_resume``      read and check ``last.pt`` (:mod:`.checkpoint`), restore it, or start afresh
- ``_open``        the loaders, the untrained network's score, the dvclive logs
- per epoch: ``train_epoch`` + ``validate`` (:mod:`.epoch`), ``_end_epoch`` (the plateau lr, the
  weighting's epoch hook, early stopping, the best score, the epoch's record), ``_checkpoint``
  (``best.pt``, ``last.pt``, then the dvclive record), ``_interrupt`` (``stop_after_epochs``)
- ``_finish``      the summary, the ONNX export, ``last.pt`` marked finished
"""
from __future__ import annotations

import hashlib
import json
import logging
import random
import time
import zipfile
import zlib
from pathlib import Path
from typing import Optional

import numpy as np
import torch

from . import distributed as ddp
from ...core import catalog, io
from ...core.params import Params
from ...core.determinism import release_torch_pins, resolve_device, set_determinism, set_threads
from ...core.errors import RunError
from ...core.layout import BEST_HASH_KEY
from ...core.machine import bounded, cpu_name
from ...data.loader import make_loader, to_device
from ..losses import de_loss_factor
from ..models import build_model
from ..weighting import build_weighting, network_tasks, weighting_settings
from .checkpoint import (clear_for_start, discard_unsaved, load_resumable, mark_finished, read_checkpoint, restore,
                         save_best, save_last)
from .capture import captured_step
from .epoch import selection_score, split_scores, train_epoch, validate
from .precision import make_grad_scaler, maybe_compile, resolve_precision, to_channels_last
from .provenance import source_fingerprint
from ..plan import PlannedRun
from ..schedule import EarlyStop, Plateau
from .state import RunSpec, RunState

log = logging.getLogger(__name__)

__all__ = ["train_run", "run_seed", "run_digest", "cache_fingerprint", "finished_runs", "seed_everything",
           "make_optimizer", "selection_score"]


def run_seed(params: Params, dataset_id: str, seed: int) -> int:
    """RNG seed of one run, derived from ``params.seed``, the dataset and the run's training seed
    ``seed`` (one of ``params.seeds_of(group, dataset)``; adding a seed changes no other run). It
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
    """Content hash of the cache's files outside its ``test/`` split (decides whether to resume).
    Paths are taken relative to ``cache_dir``, so a cache anywhere (under a folder named ``test``
    too) hashes the same; a cache with no training or validation file is a :class:`RunError`."""
    cache_dir, h = Path(cache_dir), hashlib.sha256()
    splits: set[str] = set()
    for path in sorted(p for p in cache_dir.rglob("*") if p.is_file()):
        rel = path.relative_to(cache_dir)
        if rel.parts[0] == "test":
            continue
        splits.add(rel.parts[0])
        h.update(str(rel).encode())
        with path.open("rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 22), b""):
                h.update(chunk)
    missing = [s for s in ("train", "val") if s not in splits]
    if missing:
        raise RunError(f"{cache_dir}: no {' or '.join(missing)} files to fingerprint (expected <cache>/train/*.npy "
                       "and <cache>/val/*.npy)")
    return h.hexdigest()


def run_digest(params: Params, run: PlannedRun, rng_seed: int, cache_hash: str, world_size: int) -> str:
    """Digest of everything that decides a run's result; it gates resuming and skipping.

    It covers the source code (:func:`~compact_perception.learning.training.provenance.source_fingerprint`),
    the torch version, ``scale``, the run's RNG seed ``rng_seed`` (:func:`run_seed`), every ``train``
    param except the recipes (the run's own merged recipe is covered whole) and the settings that
    cannot change a result (``num_workers``, ``parallel_runs``, ``device``), the run's epoch cap, the
    training and validation data (``cache_hash``, :func:`cache_fingerprint`), and the number of processes.
    """
    train = params.train.model_dump(exclude={"models", "recipe", "num_workers", "parallel_runs", "device"})
    blob = json.dumps({
        "code": source_fingerprint(), "torch": torch.__version__, "scale": params.scale,
        "dataset": run.dataset, "model": run.model, "seed": rng_seed, "train": train,
        "recipe": run.recipe.model_dump(), "max_epochs": run.max_epochs, "data": cache_hash,
        "world_size": world_size,
    }, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


#: A run's summary.json is a few kB: a larger file is not one (read no further).
MAX_SUMMARY_BYTES = 1 << 20


def _whole_archive(path: Path) -> bool:
    """Whether ``path`` is a whole checkpoint archive (its zip directory, read from its end, lists
    a pickle): a truncated ``last.pt`` is left to the run's job, which names it."""
    try:
        with zipfile.ZipFile(path) as archive:
            return any(name.endswith("data.pkl") for name in archive.namelist())
    except (OSError, zipfile.BadZipFile):
        return False


def finished_runs(params: Params, runs: list[PlannedRun], world_size: int = 1) -> dict[str, dict]:
    """``{run name: summary}`` of the runs already complete for this code, params and data: their
    ``summary.json`` (written last) carries the digest this run would have and ``last.pt`` is a whole
    archive.
    Decided where the stage plans its runs, before any job is handed to an executor, so a finished
    run costs no job (no worker, no cluster job); each cache is hashed once, and not at all when no
    run has a summary. A run this cannot decide (a cache or summary that does not read) is left to
    its job, which says what is wrong (:func:`_resume` decides the same way inside the job)."""
    candidates = [r for r in runs if r.paths.summary.is_file() and _whole_archive(r.paths.last)]
    hashes: dict[Path, Optional[str]] = {}
    done: dict[str, dict] = {}
    for run in candidates:
        cache = run.paths.cache_dir
        if cache not in hashes:
            try:
                hashes[cache] = cache_fingerprint(cache)
            except (OSError, RuntimeError):  # RunError: no train/val files
                hashes[cache] = None
        try:
            with run.paths.summary.open("rb") as fh:
                summary = json.loads(fh.read(MAX_SUMMARY_BYTES + 1)[:MAX_SUMMARY_BYTES])
        except (OSError, ValueError, RecursionError):
            continue
        if hashes[cache] is None or not isinstance(summary, dict):
            continue
        digest = run_digest(params, run, run_seed(params, run.dataset, run.seed), hashes[cache], world_size)
        if summary.get("digest") == digest:
            log.info("%s: already complete for this code, params and data", run.paths.run_dir)
            done[run.name] = summary
    return done


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


def _log_epoch(live, record: dict) -> None:
    live.step = record["epoch"]
    for k, v in record.items():
        if k != "epoch":
            live.log_metric(k, v)
    live.next_step()


def _check_inputs(params: Params, run: PlannedRun, per_rank_batch: int) -> dict:
    """Everything a run needs, checked before anything is written; returns the cache meta. The
    messages name the params key of the run's recipe."""
    from ...core.cache import CacheError, read_meta, read_split

    recipe, where, cache_dir = run.recipe, run.recipe_key, run.paths.cache_dir
    group = catalog.MODELS[run.model].group
    takes_de_loss = catalog.GROUPS[group].de_loss
    if takes_de_loss and recipe.de_loss is None:
        raise RunError(f"{where}.de_loss: required for a {group} model (huber or smooth_l1)")
    if not takes_de_loss and recipe.de_loss is not None:
        raise RunError(f"{where}.de_loss: a {group} model does not take it (it keeps its own losses); "
                       "remove the key (set it to null where the recipe inherits it from train.recipe)")
    weighting_settings(recipe, compiled=params.train.compile)
    meta = read_meta(cache_dir)
    n_train = len(read_split(cache_dir, "train", meta).frame_ids)
    n_val = len(read_split(cache_dir, "val", meta).frame_ids)
    if n_train < per_rank_batch:
        raise RunError(f"train.batch_size: {params.train.batch_size} needs at least {per_rank_batch} training "
                       f"frames per process, {cache_dir / 'train'} has {n_train}")
    if n_val == 0:
        raise CacheError(f"{cache_dir / 'val'}: the validation split is empty")
    return meta


def _devices(preference: str) -> tuple[torch.device, ddp.Dist]:
    """The device of this process and its place among ``torchrun``'s processes (if any)."""
    device = resolve_device(preference)
    dist_ = ddp.init_from_env(device.type)
    if dist_.enabled and device.type == "cuda":
        device = torch.device("cuda", dist_.local_rank)
    return device, dist_


def train_run(params: Params, run: PlannedRun, *, stop_after_epochs: int | None = None,
              dtype: torch.dtype = torch.float32, progress: bool = True) -> dict:
    """Train the planned run ``run`` (:func:`~compact_perception.learning.plan.planned_run`: its network,
    recipe, training seed and epoch cap) from ``run.paths.cache_dir`` into ``run.paths.run_dir``;
    a compact network's own run (``run.export_onnx``) also writes its best checkpoint as
    ``model.onnx``. ``progress``: a per-step progress bar (off in a stage's worker processes,
    :mod:`.parallel`, which log epochs).

    ``stop_after_epochs`` ends the process after that many epochs of this call without
    writing the summary (it simulates an interruption, for tests). A failure to write a
    checkpoint (a full disk) raises :class:`RunError`; a run that never saved an epoch then
    leaves nothing behind.
    """
    tp = params.train
    if tp.precision != "fp32":  # mixed precision wants the CPU's own (bf16/AMX) kernels: no pins, no bit promise
        release_torch_pins()
    device, dist_ = _devices(tp.device)
    per_rank_batch = max(1, tp.batch_size // dist_.world_size)
    meta = _check_inputs(params, run, per_rank_batch)
    set_threads(tp.num_threads)
    rng_seed = run_seed(params, run.dataset, run.seed)
    digest = run_digest(params, run, rng_seed, cache_fingerprint(run.paths.cache_dir), dist_.world_size)
    spec = RunSpec(params=params, planned=run, device=device, dist=dist_, rng_seed=rng_seed, digest=digest, per_rank_batch=per_rank_batch,
                   num_seg_classes=len(meta["seg_classes"]), dtype=dtype, stop_after_epochs=stop_after_epochs,
                   progress=progress)
    try:
        return _train(spec)
    except InterruptedError:  # stop_after_epochs (an OSError subclass): not a write failure
        raise
    except RunError:  # a diverged or damaged run: what it saved stays, a run that saved nothing leaves nothing
        discard_unsaved(run.paths, dist_)
        raise
    except OSError as err:  # a full disk, a read-only folder: say which file, leave no half-run
        discard_unsaved(run.paths, dist_)
        raise RunError(f"{err.filename or run.paths.run_dir}: could not write the run ({err.strerror or err})") \
            from None


def _train(spec: RunSpec) -> dict:
    """The run's steps: setup, resume, every remaining epoch (each checkpointed), finish."""
    run = _setup(spec)
    done = _resume(run)
    if done is not None:
        return done
    _open(run)
    for epoch in range(run.next_epoch, run.spec.planned.max_epochs):
        if run.stopped_early:
            break
        train_m = train_epoch(run, epoch)
        record, improved = _end_epoch(run, epoch, train_m, split_scores(validate(run)))
        _checkpoint(run, record, improved)
        _interrupt(run, epoch)
    return _finish(run)


def _setup(spec: RunSpec) -> RunState:
    """Seed the RNGs and build what trains: the network (channels-last, compiled forward if asked),
    the loss weighting, the optimiser, the plateau schedule, early stopping, the precision."""
    tp, planned = spec.params.train, spec.planned
    recipe = planned.recipe
    set_determinism(spec.device, tp.deterministic, tp.tf32)  # before the first kernel (cuBLAS reads its env once)
    seed_everything(spec.rng_seed)
    tasks = network_tasks(recipe, catalog.MODELS[planned.model].tasks)  # one task for the study's single-task nets
    model = build_model(planned.model, planned.dataset, tasks).to(device=spec.device, dtype=spec.dtype)
    if tp.channels_last:
        model = to_channels_last(model)
    weighting = build_weighting(recipe, model.tasks, model, plateau_patience=tp.plateau_patience,
                                plateau_factor=tp.plateau_factor)
    if spec.dist.enabled:  # DWA's epoch means, MGN's L_i(0): agreed over the ranks before they set weights
        weighting.ranks = spec.dist
    optimizer = make_optimizer(recipe, model.parameters())
    plateau = Plateau(tp.plateau_patience, tp.plateau_factor, recipe.lr_min, recipe.plateau_rule,
                      tp.plateau_threshold)
    de_factor = de_loss_factor(recipe.de_loss) if recipe.de_loss is not None else 1.0
    stopper = EarlyStop(spec.params.patience_of(tp))
    precision = resolve_precision(tp.precision, spec.device)
    scaler = make_grad_scaler(spec.device, precision)
    forward = maybe_compile(model, tp.compile)
    run = RunState(spec, model, forward, weighting, optimizer, plateau, stopper, scaler, precision, de_factor,
                   lr=recipe.lr)
    run.captured = captured_step(run)  # train.cuda_graphs: None on a CPU and wherever a step cannot be captured
    return run


def _resume(run: RunState) -> Optional[dict]:
    """Continue after the last finished epoch when ``last.pt`` is of this run (its digest), else
    start afresh; returns the summary of a run already complete for this code, params and data."""
    spec, paths = run.spec, run.spec.planned.paths
    state = load_resumable(paths.last, spec.digest)
    if state is not None and state.get("finished") and paths.summary.exists():
        log.info("%s: already complete for this code, params and data", paths.run_dir)
        ddp.shutdown(spec.dist)
        return json.loads(paths.summary.read_text())
    if spec.dist.is_main:
        clear_for_start(paths, resuming=state is not None)
    ddp.barrier(spec.dist)
    if state is not None:
        restore(run, state)
        log.info("%s: resuming after epoch %d", paths.run_dir, state["epoch"] + 1)
    return None


def _open(run: RunState) -> None:
    """The loaders, the untrained network's validation score (the reference training must beat,
    taken once per run) and, on rank 0, the dvclive logs replayed from the history."""
    from dvclive import Live

    spec, tp, planned = run.spec, run.spec.params.train, run.spec.planned
    channels = catalog.MODELS[planned.model].lidar_channels
    workers = bounded(tp.num_workers)  # at most the usable cores (core.machine): no result changes
    labelled = getattr(run.model, "labelled_maps", ())  # class maps whose labelled pixels the loader finds
    pinned = spec.device.type == "cuda"  # page-locked host batches: the copies to the GPU do not block
    run.val_loader = make_loader(planned.paths.cache_dir, "val", channels, spec.per_rank_batch, shuffle=False,
                                 seed=spec.rng_seed, num_workers=workers, drop_last=False,
                                 distributed=spec.dist.enabled, labelled=labelled, pin_memory=pinned)
    if run.untrained_score is None:  # the Kaiming-initialised network
        run.untrained_score = selection_score(validate(run))
        log.info("%s untrained val score %.4f", planned.name, run.untrained_score)
    run.train_loader = make_loader(planned.paths.cache_dir, "train", channels, spec.per_rank_batch, shuffle=True,
                                   seed=spec.rng_seed, num_workers=workers, drop_last=True,
                                   distributed=spec.dist.enabled, labelled=labelled, pin_memory=pinned)
    if spec.dist.is_main:
        run.live = Live(str(planned.paths.live), dvcyaml=False, save_dvc_exp=False)
        for record in run.history:  # the logs hold exactly the epochs the checkpoint holds
            _log_epoch(run.live, record)
    run.started = time.perf_counter()


def _end_epoch(run: RunState, epoch: int, train_m: dict, val_m: dict) -> tuple[dict, bool]:
    """The epoch's verdicts (section IV-D): the plateau lr, the weighting's epoch hook, early
    stopping and the best score; returns the epoch's record (appended to the history) and whether
    the validation score is the best so far."""
    score = selection_score(val_m)
    plateau_improved, run.lr = run.plateau.step(score, run.lr)
    run.weighting.on_epoch_end(plateau_improved)
    if run.spec.dist.enabled:  # weights it set (DWA's) come from sums over the ranks: already agreed
        run.synced_w = run.weighting.w
    run.stopped_early = run.stopper.step(score)
    improved = score < run.best_score  # the best checkpoint: any drop (both plateau rules)
    if improved:
        run.best_score, run.best_epoch = score, epoch
    record = {"epoch": epoch, "lr": run.optimizer.param_groups[0]["lr"], "val_score": score,
              **{f"train/{k}": v for k, v in train_m.items()}, **{f"val/{k}": v for k, v in val_m.items()},
              **run.weighting.log_values()}
    run.history.append(record)
    log.info("%s epoch %d: val score %.4f%s", run.spec.planned.name, epoch + 1, score,
             " (best)" if improved else "")
    return record, improved


def _checkpoint(run: RunState, record: dict, improved: bool) -> None:
    """Rank 0 saves the epoch (``best.pt`` when it improved, ``last.pt``) and then logs it: the
    checkpoint first, so the logs never hold an epoch it lacks."""
    if run.spec.dist.is_main:
        if improved:
            save_best(run, record["epoch"])
        save_last(run, record["epoch"])
        _log_epoch(run.live, record)
    ddp.barrier(run.spec.dist)


def _interrupt(run: RunState, epoch: int) -> None:
    """``stop_after_epochs``: end the process (InterruptedError) after that many epochs of this
    call, unless the run is at its last epoch."""
    run.epochs_this_call += 1
    limit = run.spec.stop_after_epochs
    if limit is not None and run.epochs_this_call >= limit and epoch + 1 < run.spec.planned.max_epochs:
        if run.live is not None:
            run.live.end()
        ddp.shutdown(run.spec.dist)
        raise InterruptedError(f"stopped after epoch {epoch + 1} (stop_after_epochs)")


def _export_best(run: RunState) -> dict:
    """Write the best checkpoint's network as ONNX (issue 15) and check it against PyTorch on one
    validation frame; returns the largest absolute output difference."""
    from ..onnx_export import export_onnx

    spec, paths = run.spec, run.spec.planned.paths
    best = read_checkpoint(paths.best, f"delete {paths.last} to retrain from scratch")
    run.model.load_state_dict(best["model"])
    batch = to_device(next(iter(run.val_loader)), spec.device, spec.num_seg_classes)
    one = {k: v[:1] for k, v in batch.items()}
    report = export_onnx(run.model, one, paths.onnx)
    log.info("%s: ONNX max abs difference to PyTorch %.2e", paths.onnx, report["max_abs_diff_all"])
    return {"file": paths.onnx.name, "max_abs_diff": float(report["max_abs_diff_all"])}


def _device_name(device: torch.device) -> str:
    """The GPU's name, or the CPU's as the OS names it."""
    return torch.cuda.get_device_name(device) if device.type == "cuda" else f"CPU: {cpu_name()}"


def _finish(run: RunState) -> dict:
    """The run's summary (written last: the run is complete), the ONNX export of a compact
    network, and ``last.pt`` marked finished."""
    spec, planned = run.spec, run.spec.planned
    summary = {
        "dataset": planned.dataset, "model": planned.model, "rng_seed": spec.rng_seed, "best_epoch": run.best_epoch,
        "best_val_score": run.best_score, "untrained_val_score": run.untrained_score,
        "epochs_run": len(run.history), "max_epochs": run.spec.planned.max_epochs, "stopped_early": run.stopped_early,
        # why it ended (section IV-D): validation stopped improving, or the safety cap
        "stop_reason": catalog.STOP_PLATEAU if run.stopped_early else catalog.STOP_CAP,
        "train_seconds": round(run.elapsed(), 2),
        "params": int(sum(p.numel() for p in run.model.parameters())), "world_size": spec.dist.world_size,
        # where and how it ran: train.device and train.precision as resolved on this machine ("auto" is
        # not an answer), with the device's name
        "device": spec.device.type, "device_name": _device_name(spec.device), "precision": run.precision,
        "final_weights": {k: v for k, v in (run.history[-1] if run.history else {}).items() if k.startswith("w_")},
        "digest": spec.digest,
    }
    if planned.export_onnx and spec.dist.is_main and catalog.group_of(planned.model).onnx:
        summary["onnx"] = _export_best(run)  # deployable, beside its checkpoint
    if spec.dist.is_main:
        run.live.end()
        mark_finished(planned.paths.last)
        if planned.paths.best.is_file():  # what evaluation checks the checkpoint against (a damaged copy)
            summary[BEST_HASH_KEY] = io.sha256_file(planned.paths.best)
        io.write_json(planned.paths.summary, summary)
    ddp.barrier(spec.dist)
    ddp.shutdown(spec.dist)
    return summary
