"""Test-split evaluation of one trained run (SPEC 6, paper Table II).

Every test frame is scored on its own (the network runs at ``evaluate.batch_size``, 1 by
default: a frame's outputs depend in their last bits on the batch it runs in); each metric is then reported as the
mean and the population variance over frames, as in Table II. TM (eq. 6) is reported as the TM
of the four means (equal to the mean of the per-frame TM) with its variance over frames; MV
(eq. 7) is one number, the population variance of the four test-set means, as the paper
computes it (``metrics.scores_from_means``). Per-frame scores go to a CSV (``per_frame.csv``:
``frame_id``, the task scores, ``tm``, and the depth errors), and the predictions (plus inputs
and ground truth) of the first frames are saved for the qualitative figures.

Beside the paper's metrics, ``metrics.json`` holds the ones the field expects (not in the
paper): ``class_iou`` (per-class IoU and mIoU of SS, LS and BEVP from confusion counts summed
over the test set) and ``depth`` (Eigen et al.'s depth errors on metric depth in the evaluated
range, mean and variance over frames); see :data:`CLASS_IOU_DEFINITION` and :func:`depth_definition`.
"""
from __future__ import annotations

import logging
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd
import torch
from tqdm.auto import tqdm

from ..core import catalog, io
from ..core.cache import read_meta, read_split
from ..core.params import Params, source_label
from ..core.errors import ReportInputError, RunError, checkpoint_load_reason
from ..core.layout import BEST_HASH_KEY, RunPaths, floor_paths
from ..core.depth import DEPTH_FAR_M, DEPTH_LOG_K
from ..data.loader import make_loader, to_device
from ..core.determinism import apply_policy, resolve_device, set_threads
from ..learning.metrics import (DEPTH_CONVENTION, DEPTH_METRICS, DEPTH_NEAR_M, MV_DEFINITION, class_confusion, class_iou, compute_metrics,
                      depth_errors_per_sample, mean_iou, multilabel_confusion, score_terms, scores_from_means,
                      ARGMAX_TASKS, iou_argmax_per_sample)
from .floor import TRIVIAL, fit_trivial, floor_of, margins
from ..learning.models import build_model
from ..learning.plan import PlannedRun

log = logging.getLogger(__name__)

TASK_METRIC = {t: catalog.metric_of(t) for t in catalog.task_ids()}  # de -> mae_de, ... (the registry)


SCORE_COLUMNS: tuple[str, ...] = catalog.metric_keys()
#: Per-frame column suffix of a class map's IoU by the arg-max rule (``iou_ss_argmax``).
ARGMAX_SUFFIX = "_argmax"
ARGMAX_COLUMNS: tuple[str, ...] = tuple(f"{catalog.metric_of(t)}{ARGMAX_SUFFIX}" for t in ARGMAX_TASKS)
ARGMAX_DEFINITION = (
    "the other scoring rule for the class maps (SS, LS): eq. (5) on the arg-max class map (each pixel's "
    "highest-scoring class), pixels without a ground-truth label left out, per view and averaged over views; "
    "mean and population variance over frames. Table II scores every row by eq. (5) on the raw outputs (the "
    "paper's rule, at the labelled pixels of SS and LS too), which lets a sigmoid head predict nothing and leaves a "
    "softmax head below 0.5 where it is unsure"
)
DEPTH_COLUMNS: tuple[str, ...] = tuple(DEPTH_METRICS.keys())
CLASS_IOU_DEFINITION = (
    "per-class IoU = TP / (TP + FP + FN) from counts summed over all test frames; SS and LS: predicted class = "
    "arg-max over the classes, pixels without a ground-truth label left out; BEVP: each class a binary mask, "
    "prediction > 0.5 against ground truth > 0.5; a class with TP + FP + FN = 0 (absent from prediction and ground "
    "truth) has IoU null and is left out of mIoU; all classes of the cache count, including 'unlabeled'/'noise'"
)
#: Significant digits of the depth errors' mean and variance in metrics.json (:func:`summarise_depth`).
DEPTH_DIGITS = 12


def depth_definition(max_m: float) -> str:
    """metrics.json's words for the ``depth`` block at the evaluated maximum ``max_m``."""
    return (
        f"metric depth d = {DEPTH_FAR_M:g} m * exp((x - 1) * {DEPTH_LOG_K}) from the cache's CARLA log depth x in [0, 1]; "
        f"evaluated range {DEPTH_NEAR_M:.2f} m .. {max_m:g} m by the field's convention ({DEPTH_CONVENTION}): the "
        f"prediction clamped to that range, pixels whose ground truth is x = 0 (no depth), x = 1 (1000 m far clip, sky) "
        f"or deeper than {max_m:g} m left out; per frame over the valid pixels of the 4 views: "
        + ", ".join(DEPTH_METRICS[k].definition for k in DEPTH_COLUMNS)
        + f"; reported as mean and population variance over the frames that have valid pixels, rounded to "
        f"{DEPTH_DIGITS} significant digits (the same bytes on every x86-64 machine: docs)"
    )


def frame_scores(metrics: dict[str, float]) -> dict[str, float]:
    """Per-frame scores: the task scores, and the per-frame scores of ``catalog.SCORES`` (TM, eq. 6)
    when all four tasks are present.
    No per-frame MV: eq. (7) is computed once, from the test-set means (:func:`summarise`)."""
    out = {k: float(v) for k, v in metrics.items() if k in TASK_METRIC.values()}
    terms = score_terms(out)
    if terms is not None:
        out.update({k: float(catalog.SCORES[k].of_terms(*terms)) for k in catalog.per_frame_scores()})
    return out


def _mean_var(x: pd.Series) -> dict[str, float]:
    return {"mean": float(x.mean()), "var": float(x.var(ddof=0))}


def summarise(per_frame: pd.DataFrame) -> dict[str, dict[str, float | str]]:
    """Table II's numbers: mean and population variance over frames of every task score;
    ``tm`` = TM of the four means (eq. 6; equal to the mean of the per-frame TM) with the
    variance of the per-frame TM; ``mv`` = ``{"value": MV of the four means (eq. 7),
    "definition": ...}``."""
    out: dict[str, dict[str, float | str]] = {
        c: _mean_var(per_frame[c]) for c in SCORE_COLUMNS if c in per_frame}
    derived = scores_from_means({c: v["mean"] for c, v in out.items()})
    if derived:
        tm_frames = per_frame["tm"] if "tm" in per_frame else None
        out["tm"] = {"mean": derived["tm"], "var": float(tm_frames.var(ddof=0)) if tm_frames is not None else 0.0}
        out["mv"] = {"value": derived["mv"], "definition": MV_DEFINITION}
    return out


def summarise_argmax(per_frame: pd.DataFrame) -> dict | None:
    """Mean and variance over frames of the arg-max-rule IoUs (:data:`ARGMAX_COLUMNS`) present."""
    out: dict = {c[: -len(ARGMAX_SUFFIX)]: _mean_var(per_frame[c]) for c in ARGMAX_COLUMNS if c in per_frame}
    return {**out, "definition": ARGMAX_DEFINITION} if out else None


def _round_sig(x: float, digits: int = DEPTH_DIGITS) -> float:
    """``x`` to ``digits`` significant digits (a last-bit difference of the sum below it vanishes)."""
    return float(f"{x:.{digits}g}")


def summarise_depth(per_frame: pd.DataFrame, max_m: float = DEPTH_FAR_M) -> dict | None:
    """Mean and variance over frames (those with valid pixels) of the depth errors, rounded to
    :data:`DEPTH_DIGITS` significant digits: their per-frame values pass through exp, log and
    sqrt, whose last bit the project pins to one instruction set but cannot prove identical on
    every CPU, and the report prints 2-3 decimals."""
    if not all(c in per_frame for c in DEPTH_COLUMNS):
        return None
    ok = per_frame[DEPTH_COLUMNS[0]].notna()  # every depth metric is NaN exactly on frames without valid pixels
    out: dict = {c: {k: _round_sig(v) for k, v in _mean_var(per_frame.loc[ok, c]).items()} if ok.any() else None
                 for c in DEPTH_COLUMNS}
    out.update({"n_frames": int(ok.sum()), "max_m": float(max_m), "definition": depth_definition(max_m)})
    return out


class ClassCounts:
    """Per-class TP / FP / FN summed over the test set, per task (SS, LS: multi-class; BEVP:
    multi-label)."""

    def __init__(self) -> None:
        self.counts: dict[str, list[np.ndarray]] = {}

    def add(self, outputs: dict[str, torch.Tensor], targets: dict[str, torch.Tensor]) -> None:
        for t in ("ss", "ls", "bevp"):
            if t in outputs and t in targets:
                fn = multilabel_confusion if t == "bevp" else class_confusion
                new = [c.numpy() for c in fn(outputs[t], targets[t])]
                old = self.counts.get(t)
                self.counts[t] = new if old is None else [a + b for a, b in zip(old, new)]

    def summary(self, names: dict[str, list[str]]) -> dict:
        """``{task: {"miou", "n_classes_in_miou", "classes": {name: iou or None}}, "definition"}``."""
        out: dict = {}
        for t in sorted(self.counts):
            tp, fp, fn = self.counts[t]
            ious = class_iou(tp, fp, fn)
            labels = names.get(t) or [str(i) for i in range(len(ious))]
            if len(labels) != len(ious):
                labels = [str(i) for i in range(len(ious))]
            m = mean_iou(ious)
            out[t] = {"miou": None if np.isnan(m) else m, "n_classes_in_miou": int(np.isfinite(ious).sum()),
                      "classes": {n: (None if np.isnan(v) else float(v)) for n, v in zip(labels, ious)}}
        if out:
            out["definition"] = CLASS_IOU_DEFINITION
        return out


def _compact_prediction(task: str, pred: torch.Tensor) -> np.ndarray:
    """Predictions in the cache's compact form (class maps / masks / depth)."""
    p = pred[0].float().cpu()
    if task == "de":
        return p.numpy().astype(np.float16)
    if task == "ss":
        return p.argmax(dim=1).numpy().astype(np.uint8)  # (V,C,S,S) -> (V,S,S)
    if task == "ls":
        return p.argmax(dim=0).numpy().astype(np.uint8)
    return (p > 0.5).numpy().astype(np.uint8)


def read_best(run: PlannedRun, *, mmap: bool = False) -> dict:
    """The run's ``best.pt`` read with ``weights_only=True`` (tensors and plain containers only, so a
    crafted file cannot run code: ``runs/`` can come from a shared DVC cache). FileNotFoundError
    naming it where the run wrote none; RunError where it is not a checkpoint. ``mmap``: the
    tensors stay memory-mapped, unread (a check of the file before the work, not a load)."""
    best, what = run.paths.best, f"{run.model} on {run.dataset}"
    if not best.is_file():
        raise FileNotFoundError(f"{best}: no best checkpoint; has the training of {run.dataset}/{run.model} finished?")
    try:
        checkpoint = torch.load(best, map_location="cpu", weights_only=True, mmap=mmap)
    except (RuntimeError, ValueError, AttributeError, pickle.UnpicklingError, EOFError) as err:
        raise RunError(f"{best}: not a checkpoint of {what} ({checkpoint_load_reason(err)})") from None
    if not isinstance(checkpoint, dict) or "model" not in checkpoint:
        raise RunError(f"{best}: not a checkpoint of {what} (no 'model' state)")
    return checkpoint


def check_best(run: PlannedRun) -> bool:
    """The run's ``best.pt`` against the SHA-256 its training recorded in ``summary.json`` when the
    run finished (``best_sha256``): :class:`RunError` naming the file where they differ (a copy
    damaged in a DVC remote or on a disk, or replaced), before the checkpoint is trusted. ``False``,
    with one log line, where no hash is recorded (a run trained before runs recorded one, or not
    finished): it is evaluated unchecked, as before."""
    best, summary = run.paths.best, run.paths.summary
    if not best.is_file():
        return False  # read_best names it
    try:
        want = io.read_json(summary).get(BEST_HASH_KEY) if summary.is_file() else None
    except ReportInputError as err:
        raise RunError(str(err)) from None
    if want is None:
        log.info("%s: no hash recorded when it was written (%s has no %s); evaluated unchecked", best,
                 summary.name, BEST_HASH_KEY)
        return False
    if not isinstance(want, str):
        raise RunError(f"{summary}: {BEST_HASH_KEY}: expected a SHA-256 hex string, got {type(want).__name__}")
    got = io.sha256_file(best)
    if got != want:
        raise RunError(f"{best}: does not match the hash recorded when it was written (SHA-256 {got[:16]}..., "
                       f"{summary} records {want[:16]}...); fetch it again or retrain the run")
    return True


def load_trained(run: PlannedRun) -> tuple[torch.nn.Module, int]:
    """The network of the run's ``best.pt`` (:func:`read_best`; built for the tasks it was trained
    for), in eval mode, and the epoch it was saved at."""
    checkpoint = read_best(run)
    try:
        model = build_model(run.model, run.dataset, checkpoint.get("tasks"))  # the tasks it was trained for
        model.load_state_dict(checkpoint["model"])
    except (RuntimeError, KeyError, ValueError) as err:
        raise RunError(f"{run.paths.best}: not a checkpoint of {run.model} on {run.dataset} "
                       f"({' '.join(str(err).split())[:200]})") from None
    return model.eval(), int(checkpoint.get("epoch", -1))


def _frame(tensors: Mapping[str, torch.Tensor], i: int, n: int) -> dict[str, torch.Tensor]:
    """Frame ``i`` of a batch of ``n`` as a batch of one (the batch itself when ``n == 1``)."""
    return dict(tensors) if n == 1 else {k: v[i:i + 1] for k, v in tensors.items()}


def _frame_row(out: Mapping[str, torch.Tensor], batch: Mapping[str, torch.Tensor], frame_id: str,
               depth_max_m: float) -> dict:
    """One test frame's scores from its outputs and targets (a batch of one)."""
    row = {"frame_id": frame_id, **frame_scores(compute_metrics(out, batch, argmax_tasks=()))}
    row.update({f"iou_{t}{ARGMAX_SUFFIX}": float(iou_argmax_per_sample(out[t], batch[t])[0])
                for t in ARGMAX_TASKS if t in out and t in batch})
    if "de" in out and "de" in batch:
        row.update({k: float(v[0]) for k, v in depth_errors_per_sample(out["de"], batch["de"], depth_max_m).items()})
    return row


def _score_frames(model: torch.nn.Module, loader, ids: list[str], n_cls: int, device: torch.device,
                  save_predictions: int, desc: str, depth_max_m: float) -> tuple[pd.DataFrame, ClassCounts, dict, dict]:
    """Per-frame scores of ``model`` over the test loader, the class counts, and the predictions and
    inputs of the first ``save_predictions`` frames. The network runs on the loader's batches; each
    frame is then scored on its own outputs, by the same code as a batch of one (the class counts
    are integer sums, the same for any batch)."""
    rows, preds, inputs = [], {t: [] for t in model.tasks}, {}
    counts = ClassCounts()
    i = 0
    with torch.no_grad():
        for raw in tqdm(loader, desc=desc, leave=False):
            batch = to_device(raw, device, n_cls)
            out = model(batch)
            n = next(iter(batch.values())).shape[0]
            for j in range(n):
                rows.append(_frame_row(_frame(out, j, n), _frame(batch, j, n), ids[i + j], depth_max_m))
            counts.add(out, batch)
            for j in range(min(n, save_predictions - i)):
                for t in model.tasks:
                    preds[t].append(_compact_prediction(t, out[t][j:j + 1]))
                for k, v in raw.items():
                    inputs.setdefault(k, []).append(v[j].numpy())
            i += n
    return pd.DataFrame(rows), counts, preds, inputs


@dataclass(frozen=True)
class Scoring:
    """How a test split is scored: where the network runs, how many frames' predictions are saved
    for the figures, the evaluated depth range (``evaluate.depth_max_m``) and the frames per
    forward pass (``evaluate.batch_size``: a network's outputs for a frame move in their last bits
    with the batch it runs in, docs/gpu.md, so only batch 1 gives the committed scores)."""

    device: torch.device
    save_predictions: int
    depth_max_m: float
    batch_size: int = 1


def score_test_split(model: torch.nn.Module, paths: RunPaths, how: Scoring, *, lidar_channels: int,
                     floor: Mapping[str, float] | None = None, extra: Mapping[str, object] | None = None) -> dict:
    """Score ``model`` (a trained network or a trivial predictor, :mod:`.floor`) on the test split of
    ``paths.cache_dir``, frame by frame (each on its own outputs), and write ``paths.metrics_path``
    (Table II's numbers and the extra metrics), ``paths.eval_dir/per_frame.csv`` and the saved
    predictions. ``lidar_channels``: the LiDAR top views the model reads; ``floor``: the per-task
    floor (:func:`.floor.floor_of`), whose margins go into ``floor_margin``; ``extra``: more keys
    for ``metrics.json``."""
    cache_dir, dataset_id, name = paths.cache_dir, paths.dataset, paths.model
    meta = read_meta(cache_dir)
    n_cls = len(meta["seg_classes"])
    device = how.device
    model.to(device).eval()
    loader = make_loader(cache_dir, "test", lidar_channels, how.batch_size, shuffle=False, seed=0, num_workers=0,
                         drop_last=False, pin_memory=torch.device(device).type == "cuda")  # non-blocking copies
    ids = read_split(cache_dir, "test", meta).frame_ids
    per_frame, counts, preds, inputs = _score_frames(model, loader, ids, n_cls, device, how.save_predictions,
                                                     f"evaluate {dataset_id}/{name}", how.depth_max_m)
    result: dict = dict(summarise(per_frame))
    for key, block in (("argmax", summarise_argmax(per_frame)),
                       ("depth", summarise_depth(per_frame, how.depth_max_m))):
        if block is not None:
            result[key] = block
    cls = counts.summary({"ss": list(meta["seg_classes"]), "ls": list(meta["seg_classes"]),
                          "bevp": list(meta.get("bev_classes") or [])})
    if cls:
        result["class_iou"] = cls
    if floor is not None:
        result["floor_margin"] = margins({k: v["mean"] for k, v in result.items() if isinstance(v, dict)
                                          and "mean" in v}, floor)
    result.update({"n_frames": len(per_frame), "source": source_label(meta.get("source", "sim")),
                   "device": torch.cuda.get_device_name() if device.type == "cuda" else "CPU", **(extra or {})})
    _write_outputs(paths.eval_dir, paths.metrics_path, result, per_frame, ids, preds, inputs, how.save_predictions)
    log.info("%s/%s test: %s", dataset_id, name,
             {k: round(v["mean"], 4) for k, v in result.items() if isinstance(v, dict) and "mean" in v})
    return result


def _write_outputs(eval_dir: Path, out_json: Path, result: dict, per_frame: pd.DataFrame, ids: list[str],
                   preds: dict, inputs: dict, save_predictions: int) -> None:
    io.write_text(eval_dir / "per_frame.csv", per_frame.to_csv(index=False, float_format="%.6f"))
    n_saved = min(save_predictions, len(per_frame))
    io.write_npz(eval_dir / "predictions.npz",
                 {"frame_ids": np.array(ids[:n_saved]), **{t: np.stack(v) for t, v in preds.items() if v}})
    gt = {f"gt_{k}": np.stack(v) for k, v in inputs.items() if k in TASK_METRIC}
    ins = {k: np.stack(v) for k, v in inputs.items() if k not in TASK_METRIC}
    io.write_npz(eval_dir / "inputs.npz", {"frame_ids": np.array(ids[:n_saved]), **ins, **gt})
    io.write_json(out_json, result)


def evaluate_run(params: Params, run: PlannedRun, floor: Mapping[str, float] | None = None) -> dict:
    """Score the run's best checkpoint on the test split of its cache into its ``metrics.json`` and
    eval folder (:func:`score_test_split`) on ``train.device`` with ``train.num_threads`` torch
    threads (the thread count is part of the result) under the training run's determinism and
    precision policy (``train.deterministic``, ``train.tf32``: :func:`~..core.determinism.apply_policy`), ``evaluate.batch_size`` frames at a time;
    ``evaluate.save_predictions`` frames' predictions saved where the run saves them
    (``run.save_predictions``: not a study arm). ``floor``: as for :func:`score_test_split`."""
    ev = params.evaluate
    set_threads(params.train.num_threads)
    device = resolve_device(params.train.device)
    apply_policy(device, params.train)  # the training run's fp32 (not TF32) and deterministic kernels
    read_meta(run.paths.cache_dir)  # a missing or broken cache is named before the checkpoint is read
    model, best_epoch = load_trained(run)
    how = Scoring(device, ev.save_predictions if run.save_predictions else 0, ev.depth_max_m, ev.batch_size)
    return score_test_split(model, run.paths, how, lidar_channels=catalog.MODELS[run.model].lidar_channels,
                            floor=floor, extra={"best_epoch": best_epoch})


def evaluate_floors(params: Params, dataset_id: str, root: Path | str = ".") -> dict[str, float]:
    """Fit every trivial predictor (:data:`.floor.TRIVIAL`) on the train split of the dataset's cache
    under ``root``, score it on the test split (on the CPU, a frame at a time, with
    ``train.num_threads`` threads) into ``results/<ds>/<id>/metrics.json`` and
    ``data/eval/<ds>/<id>/`` (:func:`~.core.layout.floor_paths`), and return the per-task floor
    (:func:`.floor.floor_of`)."""
    set_threads(params.train.num_threads)
    how = Scoring(torch.device("cpu"), params.evaluate.save_predictions, params.evaluate.depth_max_m)
    means = {}
    for tid in TRIVIAL.keys():
        paths = floor_paths(dataset_id, tid, root)
        res = score_test_split(fit_trivial(tid, paths.cache_dir), paths, how, lidar_channels=15,
                               extra={"predictor": TRIVIAL[tid].label})
        means[tid] = {k: v["mean"] for k, v in res.items() if isinstance(v, dict) and "mean" in v}
    return floor_of(means)
