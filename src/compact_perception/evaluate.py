"""Test-split evaluation of one trained run (SPEC 6, paper Table II).

Every test frame is scored on its own (batch size 1); each metric is then reported as the
mean and the population variance over frames, as in Table II. TM (eq. 6) is reported as the TM
of the four means (equal to the mean of the per-frame TM) with its variance over frames; MV
(eq. 7) is one number, the population variance of the four test-set means, as the paper
computes it (``metrics.scores_from_means``). Per-frame scores go to a CSV (``per_frame.csv``:
``frame_id``, the task scores, ``tm``, and the depth errors), and the predictions (plus inputs
and ground truth) of the first frames are saved for the qualitative figures.

Beside the paper's metrics, ``metrics.json`` holds the ones the field expects (not in the
paper): ``class_iou`` (per-class IoU and mIoU of SS, LS and BEVP from confusion counts summed
over the test set) and ``depth`` (AbsRel, RMSE in metres and delta < 1.25 on metric depth,
mean and variance over frames); see :data:`CLASS_IOU_DEFINITION` and :data:`DEPTH_DEFINITION`.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from tqdm.auto import tqdm

from .core import catalog, io
from .core.depth import DEPTH_FAR_M, DEPTH_LOG_K
from .data import make_loader, to_device
from .core.determinism import resolve_device, set_threads
from .metrics import (DEPTH_METRICS, MV_DEFINITION, class_confusion, class_iou, compute_metrics,
                      depth_errors_per_sample, mean_iou, multilabel_confusion, scores_from_means, total_metric)
from .models import build_model

log = logging.getLogger(__name__)

TASK_METRIC = {t: catalog.metric_of(t) for t in catalog.task_ids()}  # de -> mae_de, ... (the registry)


SCORE_COLUMNS: tuple[str, ...] = catalog.metric_keys()
DEPTH_COLUMNS: tuple[str, ...] = tuple(DEPTH_METRICS.keys())
CLASS_IOU_DEFINITION = (
    "per-class IoU = TP / (TP + FP + FN) from counts summed over all test frames; SS and LS: predicted class = "
    "arg-max over the classes, pixels without a ground-truth label left out; BEVP: each class a binary mask, "
    "prediction > 0.5 against ground truth > 0.5; a class with TP + FP + FN = 0 (absent from prediction and ground "
    "truth) has IoU null and is left out of mIoU; all classes of the cache count, including 'unlabeled'/'noise'"
)
DEPTH_DEFINITION = (
    f"metric depth d = {DEPTH_FAR_M:g} m * exp((x - 1) * {DEPTH_LOG_K}) from the cache's CARLA log depth x in [0, 1] (prediction "
    "clamped to [0, 1]: 3.33 m .. 1000 m); pixels with ground truth x = 0 (no depth) or x = 1 (1000 m far clip, "
    "sky) left out; per frame over the valid pixels of the 4 views: "
    + ", ".join(DEPTH_METRICS[k].definition for k in DEPTH_COLUMNS)
    + "; reported as mean and population variance over the frames that have valid pixels"
)


def frame_scores(metrics: dict[str, float]) -> dict[str, float]:
    """Per-frame scores: the task scores, and TM (eq. 6) when all four tasks are present.
    No per-frame MV: eq. (7) is computed once, from the test-set means (:func:`summarise`)."""
    out = {k: float(v) for k, v in metrics.items() if k in TASK_METRIC.values()}
    if all(k in out for k in SCORE_COLUMNS):
        out["tm"] = float(total_metric(out["mae_de"], out["iou_ss"], out["iou_ls"], out["iou_bevp"]))
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


def summarise_depth(per_frame: pd.DataFrame) -> dict | None:
    """Mean and variance over frames (those with valid pixels) of the depth errors."""
    if not all(c in per_frame for c in DEPTH_COLUMNS):
        return None
    ok = per_frame[DEPTH_COLUMNS[0]].notna()  # every depth metric is NaN exactly on frames without valid pixels
    out: dict = {c: _mean_var(per_frame.loc[ok, c]) if ok.any() else None for c in DEPTH_COLUMNS}
    out.update({"n_frames": int(ok.sum()), "definition": DEPTH_DEFINITION})
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


def evaluate_run(dataset_id: str, model_id: str, cache_dir: Path, run_dir: Path, out_json: Path,
                 eval_dir: Path, *, device_pref: str, save_predictions: int, num_threads: int) -> dict:
    """Score ``run_dir/best.pt`` on the test split of ``cache_dir`` with ``num_threads`` torch
    threads (``train.num_threads``: the thread count is part of the result)."""
    cache_dir, run_dir = Path(cache_dir), Path(run_dir)
    set_threads(num_threads)
    best = run_dir / "best.pt"
    if not best.is_file():
        raise FileNotFoundError(f"{best}: no best checkpoint; has train@{dataset_id}-{model_id} finished?")
    device = resolve_device(device_pref)
    meta = json.loads((cache_dir / "meta.json").read_text())
    n_cls = len(meta["seg_classes"])
    checkpoint = torch.load(best, map_location="cpu", weights_only=False)
    model = build_model(model_id, dataset_id, checkpoint.get("tasks"))  # the tasks it was trained for
    model.load_state_dict(checkpoint["model"])
    model.to(device).eval()
    loader = make_loader(cache_dir, "test", catalog.MODELS[model_id].lidar_channels, 1, shuffle=False, seed=0,
                         num_workers=0, drop_last=False)
    ids = json.loads((cache_dir / "test" / "frame_ids.json").read_text())
    rows, preds, inputs = [], {t: [] for t in model.tasks}, {}
    counts = ClassCounts()
    with torch.no_grad():
        for i, raw in enumerate(tqdm(loader, desc=f"evaluate {dataset_id}/{model_id}", leave=False)):
            batch = to_device(raw, device, n_cls)
            out = model(batch)
            row = {"frame_id": ids[i], **frame_scores(compute_metrics(out, batch, argmax_tasks=model.argmax_tasks))}
            if "de" in out and "de" in batch:
                row.update({k: float(v[0]) for k, v in depth_errors_per_sample(out["de"], batch["de"]).items()})
            rows.append(row)
            counts.add(out, batch)
            if i < save_predictions:
                for t in model.tasks:
                    preds[t].append(_compact_prediction(t, out[t]))
                for k, v in raw.items():
                    inputs.setdefault(k, []).append(v[0].numpy())
    per_frame = pd.DataFrame(rows)
    result: dict = dict(summarise(per_frame))
    depth = summarise_depth(per_frame)
    if depth is not None:
        result["depth"] = depth
    class_names = {"ss": list(meta["seg_classes"]), "ls": list(meta["seg_classes"]),
                   "bevp": list(meta.get("bev_classes") or [])}
    cls = counts.summary(class_names)
    if cls:
        result["class_iou"] = cls
    result.update({
        "n_frames": len(rows),
        "source": catalog.source_label(meta.get("source", "sim")),
        "device": torch.cuda.get_device_name() if device.type == "cuda" else "CPU",
        "best_epoch": int(checkpoint.get("epoch", -1)),
    })
    eval_dir = Path(eval_dir)
    io.write_text(eval_dir / "per_frame.csv", per_frame.to_csv(index=False, float_format="%.6f"))
    n_saved = min(save_predictions, len(rows))
    io.write_npz(eval_dir / "predictions.npz",
                 {"frame_ids": np.array(ids[:n_saved]), **{t: np.stack(v) for t, v in preds.items() if v}})
    gt = {f"gt_{k}": np.stack(v) for k, v in inputs.items() if k in TASK_METRIC}
    ins = {k: np.stack(v) for k, v in inputs.items() if k not in TASK_METRIC}
    io.write_npz(eval_dir / "inputs.npz", {"frame_ids": np.array(ids[:n_saved]), **ins, **gt})
    io.write_json(out_json, result)
    log.info("%s/%s test: %s", dataset_id, model_id,
             {k: round(v["mean"], 4) for k, v in result.items() if isinstance(v, dict) and "mean" in v})
    return result
