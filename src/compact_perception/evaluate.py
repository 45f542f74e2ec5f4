"""Test-split evaluation of one trained run (SPEC 6, paper Table II).

Every test frame is scored on its own (batch size 1); each metric is then reported as the
mean and the population variance over frames, as in Table II. Per-frame scores go to a CSV,
and the predictions (plus inputs and ground truth) of the first frames are saved for the
qualitative figures.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from tqdm.auto import tqdm

from . import io
from .data import make_loader, to_device
from .metrics import compute_metrics, metric_variance, total_metric
from .models import build_model
from .train import resolve_device

log = logging.getLogger(__name__)

TASK_METRIC = {"de": "mae_de", "ss": "iou_ss", "ls": "iou_ls", "bevp": "iou_bevp"}
SOURCE_LABEL = {
    "sim": "simulated (embedded world)",
    "authors": "authors' CARLA dataset",
    "nuscenes-lidarseg": "nuScenes-lidarseg",
    "simulated nuScenes-format": "simulated nuScenes-format",
}


def frame_scores(metrics: dict[str, float]) -> dict[str, float]:
    """Per-frame scores; TM (eq. 6) and MV (eq. 7) when all four tasks are present."""
    out = {k: float(v) for k, v in metrics.items() if k in TASK_METRIC.values()}
    if len(out) == 4:
        out["tm"] = float(total_metric(out["mae_de"], out["iou_ss"], out["iou_ls"], out["iou_bevp"]))
        out["mv"] = float(metric_variance(out["mae_de"], out["iou_ss"], out["iou_ls"], out["iou_bevp"]))
    return out


def summarise(per_frame: pd.DataFrame) -> dict[str, dict[str, float]]:
    """Mean and population variance over frames of every score column."""
    cols = [c for c in ("mae_de", "iou_ss", "iou_ls", "iou_bevp", "tm", "mv") if c in per_frame]
    return {c: {"mean": float(per_frame[c].mean()), "var": float(per_frame[c].var(ddof=0))} for c in cols}


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
                 eval_dir: Path, device_pref: str = "auto", save_predictions: int = 2) -> dict:
    """Score ``run_dir/best.pt`` on the test split of ``cache_dir``."""
    cache_dir, run_dir = Path(cache_dir), Path(run_dir)
    best = run_dir / "best.pt"
    if not best.is_file():
        raise FileNotFoundError(f"{best}: no best checkpoint; has train@{dataset_id}-{model_id} finished?")
    device = resolve_device(device_pref)
    meta = json.loads((cache_dir / "meta.json").read_text())
    n_cls = len(meta["seg_classes"])
    checkpoint = torch.load(best, map_location="cpu", weights_only=False)
    model = build_model(model_id, dataset_id)
    model.load_state_dict(checkpoint["model"])
    model.to(device).eval()
    loader = make_loader(cache_dir, "test", getattr(model, "lidar_channels", 15), 1, shuffle=False, seed=0,
                         num_workers=0, drop_last=False)
    ids = json.loads((cache_dir / "test" / "frame_ids.json").read_text())
    rows, preds, inputs = [], {t: [] for t in model.tasks}, {}
    with torch.no_grad():
        for i, raw in enumerate(tqdm(loader, desc=f"evaluate {dataset_id}/{model_id}", leave=False)):
            batch = to_device(raw, device, n_cls)
            out = model(batch)
            rows.append({"frame_id": ids[i], **frame_scores(compute_metrics(out, batch))})
            if i < save_predictions:
                for t in model.tasks:
                    preds[t].append(_compact_prediction(t, out[t]))
                for k, v in raw.items():
                    inputs.setdefault(k, []).append(v[0].numpy())
    per_frame = pd.DataFrame(rows)
    result = summarise(per_frame)
    result.update({
        "n_frames": len(rows),
        "source": SOURCE_LABEL.get(meta.get("source", "sim"), meta.get("source", "sim")),
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
             {k: round(v["mean"], 4) for k, v in result.items() if isinstance(v, dict)})
    return result
