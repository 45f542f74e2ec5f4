"""DVC stage train@<dataset>: every run of one dataset (compact_perception.learning.plan: each model of
``model_ids`` at its seeds, and the study's arms where the dataset is a study dataset), trained
side by side in ``train.parallel_runs`` worker processes into runs/<dataset>/, or as SLURM jobs
(compact_perception.execution: ``COMPACT_PERCEPTION_EXECUTOR``, ``cluster.yaml``; docs/cluster.md).
A run already complete for the same code, params and data is found here, before any job is
handed out, and costs none; a killed or requeued one resumes.

    python -m pipeline.train --dataset A                                  # the stage
    python -m pipeline.train --dataset A --model compact_15l_mgn --seed 0  # one run
    python -m pipeline.train --dataset A --arm uw --seed 0                 # one study run
    torchrun --standalone --nproc_per_node=2 -m pipeline.train --dataset A --model compact_15l --seed 0
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import re
import sys
from functools import partial
from pathlib import Path

from compact_perception.core.cache import CacheError
from compact_perception.core.catalog import dataset_ids, model_ids
from compact_perception.core.params import Params, ParamsError
from compact_perception.core.errors import RunError, os_error_line
from compact_perception.core.params.errors import shown
from compact_perception.learning.plan import PlannedRun, dataset_runs, recipe_of
from compact_perception.execution.executor import chosen_executor, run_jobs
from compact_perception.execution.jobs import Job, JobError, RunAloneError
from compact_perception.execution.settings import SettingsError
from compact_perception.learning.training.memory_probe import measure_in_subprocess
from compact_perception.learning.training.parallel import stage_processes
from compact_perception.learning.training.train import finished_runs, run_seed, train_run
from compact_perception.learning.weighting import weighting_settings

from ._common import stage, start, worker_logging

log = logging.getLogger("pipeline.train")


def train_one(params: Params, run: PlannedRun, *, progress: bool) -> dict:
    """One planned run, in a worker process, a cluster job or this one (``progress``: a per-step
    bar, for a run alone): its summary's stopping facts. A run that runs out of its device's memory
    fails alone (:class:`~compact_perception.execution.jobs.RunAloneError`, one line naming the run
    and what to set): the stage's other runs go on, and the worker's next run starts clean."""
    worker_logging()
    try:
        return _facts(train_run(params, run, progress=progress))
    except MemoryError as err:  # torch.OutOfMemoryError is also a RuntimeError: this run's, in one line
        line = out_of_memory_line(run, err)
    except RuntimeError as err:
        if isinstance(err, RunError) or "out of memory" not in str(err):
            raise
        line = out_of_memory_line(run, err)
    release_device_memory()  # the failed run's tensors are gone with its frames: the worker's next run starts clean
    raise RunAloneError(line)


def release_device_memory() -> None:
    """Give the caching allocator's free blocks back to the GPU (after a run that ran out of memory)."""
    import gc

    import torch

    gc.collect()
    if torch.cuda.is_available():
        torch.cuda.empty_cache()


def out_of_memory_line(run: PlannedRun, err: BaseException) -> str:
    """One line for a run that ran out of memory: the run, the allocator's first line, what to set."""
    first = next((ln.strip() for ln in str(err).splitlines() if ln.strip()), type(err).__name__)[:160]
    return (f"{run.name}: out of memory ({first}); set train.parallel_runs to a lower count (fewer runs "
            "share the device) or train.batch_size lower; a restart resumes the run from its last.pt")


def _facts(summary: dict) -> dict:
    return {k: summary.get(k) for k in ("epochs_run", "best_epoch", "stop_reason")}


def _selected(params, args) -> list[PlannedRun]:
    runs = dataset_runs(params, args.dataset)
    if args.model or args.arm or args.seed is not None:
        runs = [r for r in runs if (args.model is None or (r.model == args.model and r.arm is None))
                and (args.arm is None or r.arm == args.arm) and (args.seed is None or r.seed == args.seed)]
        if not runs:
            raise ParamsError(f"{args.params}: no run of {args.dataset} with model {args.model}, arm {args.arm}, "
                              f"seed {args.seed} (the seeds and arms params.yaml lists at scale {params.scale})")
    if args.out is not None and len(runs) != 1:
        raise ParamsError(f"--out: names one run's folder, but {len(runs)} runs are selected")
    moved = {k: v for k, v in (("cache_dir", args.cache), ("run_dir", args.out)) if v is not None}
    return [r.moved(**moved) for r in runs]


#: A run's summary.json is a few kB; a larger file in an ``--out`` folder is not one.
MAX_SUMMARY_BYTES = 1 << 20
#: The training seeds an ``--out`` folder's summary is matched against (its ``rng_seed``, :func:`run_seed`).
KNOWN_SEEDS = range(1000)


def _name(value: object) -> str:
    """A dataset or model id as written, anything else shown bounded (a summary is a file's text)."""
    return value if isinstance(value, str) and re.fullmatch(r"[\w.-]{1,40}", value) else shown(value)


def other_run(params: Params, run: PlannedRun) -> str | None:
    """What the ``--out`` folder of ``run`` holds when it is another finished run (its
    ``summary.json``: another dataset, model or training seed), or cannot be told from one; ``None``
    for an empty folder, an unfinished run, or a finished run of this dataset, model and seed
    (trained again only where its code, params or data changed, as in the stage's own folders). A
    summary whose ``rng_seed`` is no seed's under this params' ``seed`` is of this run at other params."""
    folder, path = run.paths.run_dir, run.paths.summary
    if not path.exists():
        return None
    try:
        size = path.stat().st_size
        held = json.loads(path.read_bytes()[:MAX_SUMMARY_BYTES]) if size <= MAX_SUMMARY_BYTES else None
    except (OSError, ValueError, RecursionError):
        held = None
    if not isinstance(held, dict):
        return (f"{folder}: its summary.json does not read as a run's summary, so the run it holds cannot be told; "
                "give --out an empty folder or this run's own")
    ds, model, rng = held.get("dataset"), held.get("model"), held.get("rng_seed")
    seeds = {run_seed(params, run.dataset, k): k for k in [*KNOWN_SEEDS, run.seed]}
    seed = seeds.get(rng) if type(rng) is int else None
    if ds == run.dataset and model == run.model and seed in (None, run.seed):
        return None
    what = f"{_name(ds)}/{_name(model)}" + (f"/seed{seed}" if seed is not None else "")
    return (f"{folder}: holds a finished run of {what} (its summary.json), not of {run.name}; give --out an empty "
            "folder or this run's own")


def check_weightings(params: Params, params_path: str) -> None:
    """Every recipe's and study arm's weighting settings, before anything is written (one line
    naming the key of ``params_path`` that is wrong)."""
    compiled = params.train.compile
    for m in params.model_ids:
        weighting_settings(recipe_of(params, m, None), params_path, compiled=compiled)
    for arm in params.study.arm_ids:
        weighting_settings(recipe_of(params, params.study.base_model, arm), params_path, compiled=compiled)


def train_todo(params: Params, todo: list[PlannedRun], desc: str, executor, *, alone: bool = False) -> list[dict]:
    """The unfinished runs ``todo`` through ``executor``, longest first, their stopping facts in order
    (the train stage's and ``pipeline.train_all``'s one way to hand runs out). ``train.parallel_runs``
    workers; on CUDA under ``auto``, as many per GPU as the costliest run's measured memory allows
    (measured only where there are runs to share the GPU). ``alone``: one run, in this process, with a
    per-step bar."""
    probe = partial(measure_in_subprocess, params, max(todo, key=lambda r: r.cost)) if todo and not alone else None
    processes, on_gpu = stage_processes(params.train, probe)
    if not todo:
        return []
    return run_jobs(partial(train_one, params, progress=alone), [Job(r.name, r, cost=r.cost) for r in todo],
                    1 if alone else processes, desc=desc, gpu=on_gpu, executor=executor)


@stage
def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--dataset", required=True, choices=dataset_ids())
    ap.add_argument("--model", default=None, choices=model_ids(), help="only this model's runs")
    ap.add_argument("--arm", default=None, help="only this study arm's runs")
    ap.add_argument("--seed", default=None, type=int, help="only this seed's runs")
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--cache", type=Path, default=None, help="default data/cache/<dataset> (core.layout's)")
    ap.add_argument("--out", type=Path, default=None, help="one run's folder (default: core.layout's)")
    args = ap.parse_args(argv)
    params = start(args.params, workers=("train.parallel_runs", "train.num_workers"), device=True)
    try:
        check_weightings(params, args.params)
        runs = _selected(params, args)
        taken = other_run(params, runs[0]) if args.out is not None else None
        if taken:
            raise ParamsError(taken)
        executor = chosen_executor()
        finished = finished_runs(params, runs, int(os.environ.get("WORLD_SIZE", "1")))
        todo = [r for r in runs if r.name not in finished]
        trained = train_todo(params, todo, f"train {args.dataset}", executor, alone=len(runs) == 1)
        done = {**{n: _facts(s) for n, s in finished.items()}, **dict(zip((r.name for r in todo), trained))}
    except (JobError, RunError, CacheError, ParamsError, SettingsError) as err:
        sys.exit(f"error: {err}")
    except OSError as err:  # a full disk, a read-only runs/ (a run's own writes say RunError)
        sys.exit(f"error: {os_error_line(err, Path('runs') / args.dataset)}")
    for r, facts in ((r, done[r.name]) for r in runs if r.name in done):
        log.info("%s: %s epochs (best %s), stopped by %s", r.name, facts["epochs_run"], facts["best_epoch"],
                 facts["stop_reason"])


if __name__ == "__main__":
    main()
