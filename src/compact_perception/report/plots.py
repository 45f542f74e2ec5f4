"""Training curves of every run as long-format CSV files for ``dvc plots`` (one line per run).

``reports/plots/val_tm.csv``        columns ``epoch, run, val_tm``: every run (every dataset, model
                                    and seed of params.yaml), one row per logged epoch;
``reports/plots/loss_weights.csv``  columns ``epoch, run, task, weight``: every run whose loss
                                    weighting logs weights (dvclive ``live/plots/metrics/w_<task>.tsv``).

``run`` is ``<ds>/<model>/seed<k>`` (:func:`..collect.run_name`); ``epoch`` the dvclive step
(the training epoch, as ``summary.json``'s ``best_epoch`` counts it); ``val_tm`` the validation
TM (:func:`..figures.read_val_curve`: ``val/tm``, else ``val_score``, which is the model's own
share of TM for a baseline). The runs come from :func:`..collect.list_runs` with the seeds of
params.yaml, so a stale seed folder never appears; the loss-balancing study's runs follow as
``study/<arm>/seed<k>/<ds>`` (``extra_runs``). ``dvc.yaml`` plots them with the custom
templates ``.dvc/plots/by_run.json`` (colour by run) and ``weights_by_run.json`` (colour by run,
stroke dash by task), so the plots scale to any number of runs without listing them.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Sequence

from .collect import SeedSpec, list_runs, run_name, seeds_for
from .figures import read_val_curve, read_weight_curves
from .tables.formats import csv_text, write_files

log = logging.getLogger(__name__)

VAL_TM_COLUMNS: tuple[str, ...] = ("epoch", "run", "val_tm")
WEIGHT_COLUMNS: tuple[str, ...] = ("epoch", "run", "task", "weight")


def plot_rows(root: Path, datasets: Sequence[str], models: Sequence[str], seeds: SeedSpec = None,
              extra_runs: Sequence[tuple[str, Path]] = ()) -> tuple[list[list], list[list]]:
    """The rows of ``val_tm.csv`` and ``loss_weights.csv`` (runs in dataset, model, seed order,
    then ``extra_runs`` (name, run folder) as given; epochs ascending; tasks in the paper's order)."""
    runs = [(run_name(run), run.run_dir) for ds in datasets for m in models
            for run in list_runs(root, ds, m, seeds_for(seeds, m, ds))]
    val_rows: list[list] = []
    weight_rows: list[list] = []
    for name, run_dir in [*runs, *extra_runs]:
        curve = read_val_curve(run_dir)
        if curve is None or not len(curve):
            log.warning("%s: no validation curve under %s", name, run_dir / "live")
        else:
            val_rows += [[int(e), name, float(v)] for e, v in curve.items()]
        for task, s in read_weight_curves(run_dir).items():
            weight_rows += [[int(e), name, task, float(v)] for e, v in s.items()]
    return val_rows, weight_rows


def write_plot_data(root: Path, datasets: Sequence[str], models: Sequence[str], out_dir: Path,
                    seeds: SeedSpec = None, extra_runs: Sequence[tuple[str, Path]] = ()) -> list[Path]:
    """Write ``val_tm.csv`` and ``loss_weights.csv`` under ``out_dir`` (both always, with their
    header even when empty, so the DVC plots always resolve); returns the paths."""
    val_rows, weight_rows = plot_rows(root, datasets, models, seeds, extra_runs)
    paths = write_files(out_dir, {"val_tm.csv": csv_text(VAL_TM_COLUMNS, val_rows),
                                  "loss_weights.csv": csv_text(WEIGHT_COLUMNS, weight_rows)})
    log.info("plots: %d validation rows (%d runs), %d weight rows", len(val_rows), len({r[1] for r in val_rows}),
             len(weight_rows))
    return paths
