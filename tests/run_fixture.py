"""A planned run (compact_perception.learning.plan) in a test's folders: tests train and score runs as the
stages do, through ``train_run(params, run)`` and ``evaluate_run(params, run)``."""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Optional

from compact_perception.core.layout import RunPaths
from compact_perception.learning.plan import PlannedRun, planned_run

PATH_FIELDS = frozenset(f.name for f in dataclasses.fields(RunPaths))


def run_in(params: Any, model: str, cache: Path, run_dir: Path, *, arm: Optional[str] = None, seed: int = 0,
           dataset: str = "A", **fields: Any) -> PlannedRun:
    """The stage's run of ``model`` (or of study arm ``arm`` on it) at training seed ``seed``, read
    from ``cache`` and written to ``run_dir``, its metrics.json and eval folder beside that
    (``<run_dir>-metrics.json``, ``<run_dir>-eval``); ``fields``: other fields of the run or of its
    paths replaced (``export_onnx=False``, ``eval_dir=...``)."""
    run_dir = Path(run_dir)
    paths = {"cache_dir": cache, "run_dir": run_dir, "metrics_path": run_dir.parent / f"{run_dir.name}-metrics.json",
             "eval_dir": run_dir.parent / f"{run_dir.name}-eval"}
    paths.update({k: v for k, v in fields.items() if k in PATH_FIELDS})
    run = planned_run(params, dataset, model, seed, arm).moved(**paths)
    return dataclasses.replace(run, **{k: v for k, v in fields.items() if k not in PATH_FIELDS})


def nudged_replay(run: Any) -> Any:
    """A stand-in graph whose every replay runs the step, then moves the run's first parameter by
    1e-3: a replay that lands far from the eager step, which the first-replay check must refuse."""
    import torch

    from compact_perception.learning.training.capture import Uncaptured

    class Nudged(Uncaptured):
        def replay(self) -> None:
            super().replay()
            with torch.no_grad():
                p = next(run.model.parameters())
                p[(0,) * p.dim()] += 1e-3

    return Nudged()
