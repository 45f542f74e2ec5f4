"""Fake pipeline outputs for the report tests (tests/test_report.py, tests/test_claims.py).

Written from the documented layout (docs/ARCHITECTURE.md; one run per dataset, model and
training seed k), never by calling the report code under test:

    results/<ds>/<model>/seed<k>/metrics.json       {"mae_de": {"mean", "var"}, ..., "tm", "mv", "argmax", "floor_margin", ...}
    data/eval/<ds>/<model>/seed<k>/per_frame.csv    frame_id + the model's scores (+ tm, + iou_ss_argmax / iou_ls_argmax)
    runs/<ds>/<model>/seed<k>/summary.json          best_epoch, epochs_run, max_epochs, stop_reason, final_weights, ...
    runs/<ds>/<model>/seed<k>/live/plots/metrics/   val_score.tsv, val/tm.tsv (4-task models), w_<task>.tsv (MGN)
    results/<ds>/<trivial id>/metrics.json          the floor's trivial predictors (no seed)
    data/eval/<ds>/<trivial id>/per_frame.csv

Per-frame scores = the model's base + a seed shift + a shared frame difficulty + the run's own
noise; difficulty and noise are centred, so a run's test-set mean is exactly ``base + shift``
(hand-computable means and standard deviations over the seeds). Frame ids carry their cluster
(``town02_ep0003_004``: episode 3 of the world; ``scene-0003_004``: a nuScenes scene), 10 frames
each. The trivial predictors (:data:`FLOOR_BASES`, no seed shift) are far below every model.
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
#: The paper's models, the runs this fixture writes (their scores below are chosen for the tests'
#: verdicts); a model registered later has no run here, and the report leaves out what did not run.
MODELS: tuple[str, ...] = tuple(m for m in catalog.model_ids() if m in (
    "compact_1l", "compact_15l", "compact_15l_mgn", "compact_15l_mgn_authors", "gradnorm_segnet", "polarnet",
    "chen_bev"))
COMPACT: tuple[str, ...] = tuple(m for m in catalog.compact_model_ids() if m in MODELS)
BASELINES: tuple[str, ...] = tuple(m for m in MODELS if catalog.MODELS[m].group == "baseline")
MGN: tuple[str, ...] = ("compact_15l_mgn", "compact_15l_mgn_authors")
SEEDS: tuple[int, ...] = (0, 1, 2)
#: The floor's trivial predictors (compact_perception.evaluation.floor.TRIVIAL) and their test means: the
#: per-pixel one the better on MAE_DE, IoU_SS and IoU_LS, the global one on IoU_BEVP (floor_of takes
#: the better per metric): floor 0.30 / 0.30 / 0.20 / 0.35, TM of each 2.50 and 2.60.
FLOOR_BASES: dict[str, dict[str, float]] = {
    "floor_pixel": {"mae_de": 0.30, "iou_ss": 0.30, "iou_ls": 0.20, "iou_bevp": 0.30},
    "floor_global": {"mae_de": 0.35, "iou_ss": 0.25, "iou_ls": 0.15, "iou_bevp": 0.35},
}
FLOORS: tuple[str, ...] = tuple(FLOOR_BASES)
#: Frames per cluster (an episode of the world, a nuScenes scene).
CLUSTER = 10
#: The arg-max rule's IoU is this much above eq. (5)'s in the fixture (models with SS / LS heads).
ARGMAX_GAIN = 0.05

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


def frame_ids(ds: str, n: int) -> list[str]:
    """``n`` test frame ids of ``ds``, :data:`CLUSTER` consecutive frames per episode / scene."""
    head = "scene-" if ds == "nuscenes" else "town02_ep"
    return [f"{head}{i // CLUSTER:04d}_{i % CLUSTER:03d}" for i in range(n)]


def _scores(ds: str, columns: Sequence[str], n: int, base: Mapping[str, float], shift: float, noise: float,
            rng: np.random.Generator) -> pd.DataFrame:
    """Per-frame scores of ``columns``: each column's mean exactly ``base[c] -+ shift`` (a shift
    makes MAE_DE lower and the IoUs higher), plus the shared frame difficulty and centred noise."""
    difficulty = np.random.default_rng(7 + len(ds)).normal(0, 0.03, n)
    difficulty -= difficulty.mean()
    df = pd.DataFrame({"frame_id": frame_ids(ds, n)})
    for c in columns:
        e = rng.normal(0, noise, n)
        sign = 1.0 if c == "mae_de" else -1.0
        df[c] = base[c] - sign * shift + sign * difficulty + e - e.mean()
    if len(columns) == 4:
        df["tm"] = df["mae_de"] + 3 - df["iou_ss"] - df["iou_ls"] - df["iou_bevp"]
    return df


def jitter_of(model: str, seed: int, jitter: float) -> float:
    """A run's own shift (sd ``jitter``), on top of the seed shift every model shares: without it
    every model's runs move together and a paired difference does not vary over the seeds."""
    return float(jitter * np.random.default_rng([MODELS.index(model), seed, 77]).standard_normal()) if jitter else 0.0


def per_frame(ds: str, model: str, seed: int, n: int, bases: Optional[dict] = None, noise: float = 0.01,
              shift: Optional[float] = None, jitter: float = 0.0) -> pd.DataFrame:
    """One run's per-frame scores; its mean of column c is exactly ``bases[model][c] +- shift``
    (``shift``: the seed's :data:`SHIFTS` plus the run's :func:`jitter_of`); the arg-max-rule IoUs
    of its SS / LS heads :data:`ARGMAX_GAIN` above."""
    rng = np.random.default_rng(1000 * seed + 10 * MODELS.index(model) + len(ds))
    sh = (SHIFTS.get(seed, 0.0) + jitter_of(model, seed, jitter)) if shift is None else shift
    df = _scores(ds, TASKS[model], n, (bases or BASES)[model], sh, noise, rng)
    for c in ("iou_ss", "iou_ls"):
        if c in TASKS[model]:
            df[f"{c}_argmax"] = df[c] + ARGMAX_GAIN
    return df


def floor_frames(ds: str, trivial: str, n: int, bases: Optional[dict] = None, noise: float = 0.01) -> pd.DataFrame:
    """The per-frame scores of a trivial predictor (every task; no seed): means exactly ``bases[trivial]``."""
    rng = np.random.default_rng(500 + 10 * FLOORS.index(trivial) + len(ds))
    return _scores(ds, TASK_COLUMNS, n, (bases or FLOOR_BASES)[trivial], 0.0, noise, rng)


def _floor_value(bases: Mapping[str, Mapping[str, float]]) -> dict[str, float]:
    """The floor by hand: per metric the better trivial predictor's mean; TM the better TM."""
    out = {c: (min if c == "mae_de" else max)(b[c] for b in bases.values()) for c in TASK_COLUMNS}
    out["tm"] = min(b["mae_de"] + 3 - b["iou_ss"] - b["iou_ls"] - b["iou_bevp"] for b in bases.values())
    return out


def metrics_of(df: pd.DataFrame, model: str, source: str = "simulated (embedded world)",
               floor: Optional[Mapping[str, float]] = None) -> dict:
    """metrics.json as evaluate writes it: mean and population variance over frames per score;
    TM / MV of the four means (computed here by hand); the arg-max-rule IoUs; the margins over
    ``floor`` (positive = better)."""
    cols = [c for c in TASK_COLUMNS if c in df.columns]
    out: dict = {c: {"mean": float(df[c].mean()), "var": float(df[c].var(ddof=0))} for c in cols}
    if len(cols) == 4:
        m = [out["mae_de"]["mean"], 1 - out["iou_ss"]["mean"], 1 - out["iou_ls"]["mean"], 1 - out["iou_bevp"]["mean"]]
        out["tm"] = {"mean": float(sum(m)), "var": float(df["tm"].var(ddof=0))}
        out["mv"] = {"value": float(np.var(m)), "definition": "population variance of the four test-set means"}
    argmax = {c: {"mean": float(df[f"{c}_argmax"].mean()), "var": float(df[f"{c}_argmax"].var(ddof=0))}
              for c in ("iou_ss", "iou_ls") if f"{c}_argmax" in df.columns}
    if argmax:
        out["argmax"] = {**argmax, "definition": "test"}
    if "iou_ss" in cols:
        out["class_iou"] = {"ss": {"miou": 0.5, "n_classes_in_miou": 2,
                                   "classes": {"road": 0.75, "sky": 0.25, "water": None}}, "definition": "test"}
    if "mae_de" in cols:
        out["depth"] = {"abs_rel": {"mean": 0.25, "var": 0.01}, "rmse_m": {"mean": 12.5, "var": 4.0},
                        "delta_1.25": {"mean": 0.6, "var": 0.02}, "n_frames": len(df), "definition": "test"}
    if floor is not None:
        out["floor_margin"] = {c: (f - out[c]["mean"]) if c in ("mae_de", "tm") else (out[c]["mean"] - f)
                               for c, f in floor.items() if c in out}
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
              source: str = "simulated (embedded world)", curves: bool = True, stop_reason: str = "plateau",
              floor: Optional[Mapping[str, float]] = None) -> dict:
    """Every file of one run; returns its metrics dict. ``stop_reason``: ``plateau`` (early
    stopping ended it: converged) or ``max_epochs`` (the cap did); ``floor``: its dataset's floor."""
    run, metrics_path, eval_dir = run_dirs(root, ds, model, seed)
    met = metrics_of(frames, model, source, floor)
    write_json(metrics_path, met)
    eval_dir.mkdir(parents=True, exist_ok=True)
    (eval_dir / "per_frame.csv").write_text(frames.to_csv(index=False, float_format="%.10f"))
    e = n_epochs(model, seed)
    summary: dict = {"best_epoch": e - 2, "epochs_run": e, "max_epochs": 5, "stop_reason": stop_reason,
                     "train_seconds": 1.0, "final_weights": {}}
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


def floor_dirs(root: Path, ds: str, trivial: str) -> tuple[Path, Path]:
    """(results/<ds>/<id>/metrics.json, data/eval/<ds>/<id>) of a trivial predictor, as documented."""
    return root / "results" / ds / trivial / "metrics.json", root / "data" / "eval" / ds / trivial


def write_floors(root: Path, ds: str, n: int, bases: Optional[dict] = None, noise: float = 0.01,
                 source: str = "simulated (embedded world)") -> dict[str, dict]:
    """Both trivial predictors of ``ds`` (metrics.json, per_frame.csv); returns id -> metrics dict."""
    out = {}
    for t in FLOORS:
        df = floor_frames(ds, t, n, bases, noise)
        metrics_path, eval_dir = floor_dirs(root, ds, t)
        out[t] = {**metrics_of(df, t, source), "predictor": t}
        write_json(metrics_path, out[t])
        eval_dir.mkdir(parents=True, exist_ok=True)
        (eval_dir / "per_frame.csv").write_text(df.to_csv(index=False, float_format="%.10f"))
    return out


def build_tree(root: Path, datasets: Iterable[str] = ("A",), *, n_frames: int = 60, seeds: Sequence[int] = SEEDS,
               baseline_seeds: Sequence[int] = SEEDS, bases: Optional[dict] = None, noise: float = 0.01,
               models: Sequence[str] = MODELS, predictions: bool = False, efficiency: bool = False,
               curves: bool = True, floors: Optional[dict] = FLOOR_BASES, stop_reason: str = "plateau",
               jitter: float = 0.0) -> dict:
    """Every run of every (dataset, model, seed) plus cache meta, the trivial predictors of the
    floor (``floors``: their bases; ``None``: none) and, optionally, saved predictions of seed 0 and
    the benchmark's efficiency.json; ``jitter``: the sd of each run's own shift (:func:`jitter_of`).
    Returns ``{(ds, model, seed): metrics dict}`` (and ``{(ds, trivial id): metrics dict}`` for the floor)."""
    mets: dict = {}
    datasets = tuple(datasets)
    for ds in datasets:
        source = "simulated nuScenes-format" if ds == "nuscenes" else "simulated (embedded world)"
        write_json(root / "data/cache" / ds / "meta.json",
                   {"counts": {"train": 6, "val": 2, "test": n_frames}, "resolution": 8, "has_dvs": ds != "nuscenes",
                    "source": "sim"})
        if floors is not None:
            mets.update({(ds, t): m for t, m in write_floors(root, ds, n_frames, floors, noise, source).items()})
        for m in models:
            for k in (seeds if m in COMPACT else baseline_seeds):
                df = per_frame(ds, m, k, n_frames, bases, noise, jitter=jitter)
                mets[(ds, m, k)] = write_run(root, ds, m, k, df, source=source, curves=curves, stop_reason=stop_reason,
                                             floor=_floor_value(floors) if floors is not None else None)
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
    """(runs/<ds>/study/<arm>/seed<k>, results/<ds>/study/<arm>/seed<k>/metrics.json) as documented."""
    tail = Path(ds) / "study" / arm / f"seed{seed}"
    return root / "runs" / tail, root / "results" / tail / "metrics.json"


def write_study_run(root: Path, arm: str, seed: int, ds: str, means: Mapping[str, float], *,
                    weights: Optional[Mapping[str, Sequence[float]]] = None, train_seconds: float = 10.0,
                    epochs_run: int = 5, n_frames: int = 20) -> dict:
    """One study run: ``metrics.json`` with the given test-set means of the four tasks (variance
    0.01; TM / MV of the means by hand), its ``per_frame.csv`` (``n_frames`` frames whose means
    are exactly ``means``), ``summary.json`` (``train_seconds``, ``epochs_run``) and, with
    ``weights`` (``w_<task>`` -> one value per epoch), the dvclive weight logs. Returns the
    metrics dict."""
    run, metrics_path = study_run_dirs(root, arm, seed, ds)
    met: dict = {c: {"mean": float(means[c]), "var": 0.01} for c in TASK_COLUMNS}
    m = [means["mae_de"], 1 - means["iou_ss"], 1 - means["iou_ls"], 1 - means["iou_bevp"]]
    met["tm"] = {"mean": float(sum(m)), "var": 0.02}
    met["mv"] = {"value": float(np.var(m)), "definition": "population variance of the four test-set means"}
    met.update(n_frames=n_frames, source="simulated (embedded world)", device="CPU")
    write_json(metrics_path, met)
    eval_dir = root / "data" / "eval" / ds / "study" / arm / f"seed{seed}"
    eval_dir.mkdir(parents=True, exist_ok=True)
    df = _scores(ds, TASK_COLUMNS, n_frames, means, 0.0, 0.01, np.random.default_rng([seed, len(arm), len(ds)]))
    (eval_dir / "per_frame.csv").write_text(df.to_csv(index=False, float_format="%.10f"))
    summary: dict = {"best_epoch": epochs_run - 1, "epochs_run": epochs_run, "train_seconds": train_seconds,
                     "final_weights": {k: v[-1] for k, v in (weights or {}).items()}}
    for k, vals in (weights or {}).items():
        write_tsv(run / "live" / "plots" / "metrics" / f"{k}.tsv", k, vals)
    write_json(run / "summary.json", summary)
    return met
