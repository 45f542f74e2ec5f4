"""Fake pipeline outputs for the report tests (tests/test_report.py, tests/test_claims.py).

Written from the documented layout (docs/ARCHITECTURE.md; one run per dataset, model and
training seed k), never by calling the report code under test:

    results/<ds>/<model>/seed<k>/metrics.json       {"mae_de": {"mean", "var"}, ..., "tm", "mv", "n_frames", ...}
    data/eval/<ds>/<model>/seed<k>/per_frame.csv    frame_id + the model's scores (+ tm)
    runs/<ds>/<model>/seed<k>/summary.json          best_epoch, epochs_run, final_weights, ...
    runs/<ds>/<model>/seed<k>/live/plots/metrics/   val_score.tsv, val/tm.tsv (4-task models), w_<task>.tsv (MGN)

Per-frame scores = the model's base + a seed shift + a shared frame difficulty + the run's own
noise; difficulty and noise are centred, so a run's test-set mean is exactly ``base + shift``
(hand-computable means and standard deviations over the seeds).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable, Mapping, Optional, Sequence

import numpy as np
import pandas as pd

from compact_perception.core import catalog

TASK_COLUMNS: tuple[str, ...] = catalog.metric_keys()
#: The test metrics each model scores (its tasks' metrics), from the model registry.
TASKS: dict[str, tuple[str, ...]] = {m: tuple(catalog.metric_of(t) for t in catalog.MODELS[m].tasks)
                                     for m in catalog.model_ids()}
MODELS: tuple[str, ...] = catalog.model_ids()
COMPACT: tuple[str, ...] = catalog.compact_model_ids()
BASELINES: tuple[str, ...] = catalog.baseline_model_ids()
MGN: tuple[str, ...] = ("compact_15l_mgn", "compact_15l_mgn_authors")
SEEDS: tuple[int, ...] = (0, 1, 2)

#: Mean score per model and column: IoU_LS (PolarNet), IoU_BEVP (Chen) and TM (the
#: combination, TM 1.1) have clear winners; 15L beats 1L (TM 1.6 -> 1.39).
BASES: dict[str, dict[str, float]] = {
    "chen_bev": {"iou_bevp": 0.70},
    "polarnet": {"iou_ls": 0.90},
    "gradnorm_segnet": {"mae_de": 0.20, "iou_ss": 0.50},
    "compact_1l": {"mae_de": 0.10, "iou_ss": 0.60, "iou_ls": 0.40, "iou_bevp": 0.50},
    "compact_15l": {"mae_de": 0.09, "iou_ss": 0.65, "iou_ls": 0.50, "iou_bevp": 0.55},
    "compact_15l_mgn": {"mae_de": 0.09, "iou_ss": 0.65, "iou_ls": 0.50, "iou_bevp": 0.55},
    "compact_15l_mgn_authors": {"mae_de": 0.09, "iou_ss": 0.65, "iou_ls": 0.50, "iou_bevp": 0.55},
}
#: Seed shift of every score (added to an IoU, subtracted from MAE: a better or worse training).
SHIFTS: dict[int, float] = {0: -0.01, 1: 0.0, 2: 0.02}
WEIGHTS: dict[str, list[float]] = {"w_de": [1.0, 1.3, 1.5], "w_ss": [1.0, 0.9, 0.8], "w_ls": [1.0, 1.1, 1.2],
                                   "w_bevp": [1.0, 0.7, 0.5]}


def bases_with(**changes: Mapping[str, float]) -> dict[str, dict[str, float]]:
    """:data:`BASES` with some models' columns replaced."""
    out = {m: dict(v) for m, v in BASES.items()}
    for m, cols in changes.items():
        out[m].update(cols)
    return out


def per_frame(ds: str, model: str, seed: int, n: int, bases: Optional[dict] = None, noise: float = 0.01,
              shift: Optional[float] = None) -> pd.DataFrame:
    """One run's per-frame scores; its mean of column c is exactly ``bases[model][c] +- shift``."""
    rng = np.random.default_rng(1000 * seed + 10 * MODELS.index(model) + len(ds))
    difficulty = np.random.default_rng(7 + len(ds)).normal(0, 0.03, n)
    difficulty -= difficulty.mean()
    sh = SHIFTS.get(seed, 0.0) if shift is None else shift
    df = pd.DataFrame({"frame_id": [f"{ds}-{i:04d}" for i in range(n)]})
    for c in TASKS[model]:
        e = rng.normal(0, noise, n)
        sign = 1.0 if c == "mae_de" else -1.0
        df[c] = (bases or BASES)[model][c] - sign * sh + sign * difficulty + e - e.mean()
    if len(TASKS[model]) == 4:
        df["tm"] = df["mae_de"] + 3 - df["iou_ss"] - df["iou_ls"] - df["iou_bevp"]
    return df


def metrics_of(df: pd.DataFrame, model: str, source: str = "simulated (embedded world)") -> dict:
    """metrics.json as evaluate writes it: mean and population variance over frames per score;
    TM / MV of the four means (computed here by hand)."""
    out: dict = {c: {"mean": float(df[c].mean()), "var": float(df[c].var(ddof=0))} for c in TASKS[model]}
    if len(TASKS[model]) == 4:
        m = [out["mae_de"]["mean"], 1 - out["iou_ss"]["mean"], 1 - out["iou_ls"]["mean"], 1 - out["iou_bevp"]["mean"]]
        out["tm"] = {"mean": float(sum(m)), "var": float(df["tm"].var(ddof=0))}
        out["mv"] = {"value": float(np.var(m)), "definition": "population variance of the four test-set means"}
    if "iou_ss" in TASKS[model]:
        out["class_iou"] = {"ss": {"miou": 0.5, "n_classes_in_miou": 2,
                                   "classes": {"road": 0.75, "sky": 0.25, "water": None}}, "definition": "test"}
    if "mae_de" in TASKS[model]:
        out["depth"] = {"abs_rel": {"mean": 0.25, "var": 0.01}, "rmse_m": {"mean": 12.5, "var": 4.0},
                        "delta_1.25": {"mean": 0.6, "var": 0.02}, "n_frames": len(df), "definition": "test"}
    out.update(n_frames=len(df), source=source, device="CPU")
    return out


def write_json(path: Path, obj: object) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=2, sort_keys=True))


def write_tsv(path: Path, name: str, values: Sequence[float]) -> None:
    """A dvclive TSV: ``timestamp, step, <name>``, one row per epoch (step = epoch)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = "".join(f"{1700000000 + i}\t{i}\t{v}\n" for i, v in enumerate(values))
    path.write_text(f"timestamp\tstep\t{name.rsplit('/', 1)[-1]}\n" + rows)


def run_dirs(root: Path, ds: str, model: str, seed: int) -> tuple[Path, Path, Path]:
    """(runs/…/seed<k>, results/…/seed<k>/metrics.json, data/eval/…/seed<k>) as documented."""
    tail = Path(ds) / model / f"seed{seed}"
    return root / "runs" / tail, root / "results" / tail / "metrics.json", root / "data" / "eval" / tail


def n_epochs(model: str, seed: int) -> int:
    """Epochs logged by a run: differ between seeds (early stopping)."""
    return 3 + seed % 3


def write_run(root: Path, ds: str, model: str, seed: int, frames: pd.DataFrame, *, weights: Optional[dict] = None,
              source: str = "simulated (embedded world)", curves: bool = True) -> dict:
    """Every file of one run; returns its metrics dict."""
    run, metrics_path, eval_dir = run_dirs(root, ds, model, seed)
    met = metrics_of(frames, model, source)
    write_json(metrics_path, met)
    eval_dir.mkdir(parents=True, exist_ok=True)
    (eval_dir / "per_frame.csv").write_text(frames.to_csv(index=False, float_format="%.10f"))
    e = n_epochs(model, seed)
    summary: dict = {"best_epoch": e - 2, "epochs_run": e, "train_seconds": 1.0, "final_weights": {}}
    if curves:
        mdir = run / "live" / "plots" / "metrics"
        write_tsv(mdir / "val_score.tsv", "val_score", [1.5 - 0.1 * i + 0.01 * seed for i in range(e)])
        if len(TASKS[model]) == 4:
            write_tsv(mdir / "val" / "tm.tsv", "val/tm", [1.5 - 0.1 * i + 0.01 * seed for i in range(e)])
        if model in MGN:
            w = weights or {k: v[-1] for k, v in WEIGHTS.items()}
            for k, vals in WEIGHTS.items():
                write_tsv(mdir / f"{k}.tsv", k, (vals + [vals[-1]] * e)[:e - 1] + [w[k]])
            summary["final_weights"] = dict(w)
    elif model in MGN:
        summary["final_weights"] = dict(weights or {k: v[-1] for k, v in WEIGHTS.items()})
    write_json(run / "summary.json", summary)
    return met


def write_npz(path: Path, arrays: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as fh:
        np.savez_compressed(fh, **arrays)


def write_predictions(root: Path, ds: str, model: str, seed: int, S: int = 8) -> None:
    """``predictions.npz`` of one run (and ``inputs.npz``, which every evaluation writes)."""
    nus = ds == "nuscenes"
    n_cls, n_bev = (32, 32) if nus else (23, 9)
    rng = np.random.default_rng(seed + 100 * MODELS.index(model))
    _, _, eval_dir = run_dirs(root, ds, model, seed)
    preds: dict = {"frame_ids": np.array(["f0", "f1"])}
    if "mae_de" in TASKS[model]:
        preds["de"] = rng.random((2, 4, 1, S, S)).astype(np.float16)
    if "iou_ss" in TASKS[model]:
        preds["ss"] = rng.integers(0, n_cls, (2, 4, S, S)).astype(np.uint8)
    if "iou_ls" in TASKS[model]:
        preds["ls"] = rng.integers(0, n_cls, (2, S, S)).astype(np.uint8)
    if "iou_bevp" in TASKS[model]:
        preds["bevp"] = (rng.random((2, n_bev, S, S)) > 0.5).astype(np.uint8)
    write_npz(eval_dir / "predictions.npz", preds)
    inputs = {"frame_ids": np.array(["f0", "f1"]), "rgb": rng.integers(0, 255, (2, 4, 3, S, S)).astype(np.uint8),
              "lidar": rng.random((2, 15, S, S)).astype(np.float16),
              "gt_de": rng.random((2, 4, 1, S, S)).astype(np.float16),
              "gt_ss": rng.integers(0, n_cls, (2, 4, S, S)).astype(np.uint8),
              "gt_ls": np.full((2, S, S), 255, np.uint8),
              "gt_bevp": (rng.random((2, n_bev, S, S)) > 0.5).astype(np.uint8)}
    if not nus:
        inputs["dvs"] = rng.integers(0, 3, (2, 4, 2, S, S)).astype(np.uint8)
    write_npz(eval_dir / "inputs.npz", inputs)


def build_tree(root: Path, datasets: Iterable[str] = ("A",), *, n_frames: int = 60, seeds: Sequence[int] = SEEDS,
               baseline_seeds: Sequence[int] = SEEDS, bases: Optional[dict] = None, noise: float = 0.01,
               models: Sequence[str] = MODELS, predictions: bool = False, efficiency: bool = False,
               curves: bool = True) -> dict:
    """Every run of every (dataset, model, seed) plus cache meta (and, optionally, saved
    predictions of seed 0 and the benchmark's efficiency.json). Returns
    ``{(ds, model, seed): metrics dict}``."""
    mets: dict = {}
    datasets = tuple(datasets)
    for ds in datasets:
        source = "simulated nuScenes-format" if ds == "nuscenes" else "simulated (embedded world)"
        write_json(root / "data/cache" / ds / "meta.json",
                   {"counts": {"train": 6, "val": 2, "test": n_frames}, "resolution": 8, "has_dvs": ds != "nuscenes",
                    "source": "sim"})
        for m in models:
            for k in (seeds if m in COMPACT else baseline_seeds):
                df = per_frame(ds, m, k, n_frames, bases, noise)
                mets[(ds, m, k)] = write_run(root, ds, m, k, df, source=source, curves=curves)
                if predictions and k == min(seeds if m in COMPACT else baseline_seeds):
                    write_predictions(root, ds, m, k)
    if efficiency:
        effj: dict = {"device": "CPU (2 threads)", "is_gpu": False, "resolution": 8, "warmup": 1, "runs": 3,
                      "memory_method": "hooks", "models": {}}
        for ds in datasets:
            effj["models"][ds] = {m: {"params": 1000 * (i + 1), "size_mb": 0.5 * (i + 1), "peak_memory_mb": 10.0 + i,
                                      "fps": 1000.0 / (2.0 + i), "latency_ms": 2.0 + i, "device": "CPU (2 threads)"}
                                  for i, m in enumerate(models)}
        write_json(root / "results/benchmark/efficiency.json", effj)
    return mets


def seed_map(seeds: Sequence[int] = SEEDS, baseline_seeds: Sequence[int] = SEEDS) -> dict[str, list[int]]:
    """The report's seed lists (params ``seeds`` / ``baseline_seeds`` per model)."""
    return {m: list(seeds if m in COMPACT else baseline_seeds) for m in MODELS}


# ----------------------------------------------------------------------------- the loss-balancing study
def study_run_dirs(root: Path, arm: str, seed: int, ds: str) -> tuple[Path, Path]:
    """(runs/study/<arm>/seed<k>/<ds>, results/study/<arm>/seed<k>/<ds>/metrics.json) as documented."""
    tail = Path("study") / arm / f"seed{seed}" / ds
    return root / "runs" / tail, root / "results" / tail / "metrics.json"


def write_study_run(root: Path, arm: str, seed: int, ds: str, means: Mapping[str, float], *,
                    weights: Optional[Mapping[str, Sequence[float]]] = None, train_seconds: float = 10.0,
                    epochs_run: int = 5) -> dict:
    """One study run: ``metrics.json`` with the given test-set means of the four tasks (variance
    0.01; TM / MV of the means by hand), ``summary.json`` (``train_seconds``, ``epochs_run``) and,
    with ``weights`` (``w_<task>`` -> one value per epoch), the dvclive weight logs. Returns the
    metrics dict."""
    run, metrics_path = study_run_dirs(root, arm, seed, ds)
    met: dict = {c: {"mean": float(means[c]), "var": 0.01} for c in TASK_COLUMNS}
    m = [means["mae_de"], 1 - means["iou_ss"], 1 - means["iou_ls"], 1 - means["iou_bevp"]]
    met["tm"] = {"mean": float(sum(m)), "var": 0.02}
    met["mv"] = {"value": float(np.var(m)), "definition": "population variance of the four test-set means"}
    met.update(n_frames=40, source="simulated (embedded world)", device="CPU")
    write_json(metrics_path, met)
    summary: dict = {"best_epoch": epochs_run - 1, "epochs_run": epochs_run, "train_seconds": train_seconds,
                     "final_weights": {k: v[-1] for k, v in (weights or {}).items()}}
    for k, vals in (weights or {}).items():
        write_tsv(run / "live" / "plots" / "metrics" / f"{k}.tsv", k, vals)
    write_json(run / "summary.json", summary)
    return met
