"""Every dataset's unfinished runs handed out at once, then the pipeline: not a DVC stage, one
command around them. DVC runs its stages one after another, so on a cluster `full`'s training
would take the sum of the train stages (each about its longest run); handed out in one
submission, it takes about the longest run of all.

    COMPACT_PERCEPTION_EXECUTOR=slurm bin/venv python -m pipeline.train_all             # then dvc repro
    COMPACT_PERCEPTION_EXECUTOR=slurm bin/venv python -m pipeline.train_all --no-repro  # submit and wait only

How it meets DVC's stage order and locks (docs/cluster.md):

1. the stages the train stages depend on (each ``train@<dataset>``'s producers of its deps: the
   data stages) run first, through ``dvc repro`` of those stages: DVC's order and its own lock;
2. every dataset's runs of ``dataset_ids`` are planned as the train stages plan them, the ones
   complete for this code, params and data left out (their digests), and the rest handed to the
   executor (``COMPACT_PERCEPTION_EXECUTOR``, ``cluster.yaml``) as one submission, longest first,
   while this command holds DVC's repository lock: no ``dvc`` command can change the checkout
   meanwhile, and this command writes nothing DVC records but the runs' folders (the train stages'
   persistent outputs, which a train stage itself would write);
3. ``dvc repro`` then runs the whole pipeline (unless ``--no-repro``): each train stage finds every
   run complete, trains nothing and hands out no job, DVC records its outputs, and evaluation and
   the report follow.

Stopped part way (Ctrl-C, a job's failure), a later run of this command or ``dvc repro`` resumes
each run from its ``last.pt`` and skips the finished ones.
"""
from __future__ import annotations

import argparse
import logging
import subprocess
import sys
from pathlib import Path

from compact_perception.core.cache import CacheError
from compact_perception.core.params import ParamsError
from compact_perception.core.errors import RunError, os_error_line
from compact_perception.execution.executor import chosen_executor
from compact_perception.execution.jobs import JobError
from compact_perception.execution.settings import SettingsError
from compact_perception.learning.plan import dataset_runs
from compact_perception.learning.training.train import finished_runs

from ._common import stage, start
from .train import check_weightings, train_todo

log = logging.getLogger("pipeline.train_all")

#: The DVC stages that train, one per dataset (dvc.yaml's ``train`` matrix).
TRAIN_STAGE = "train@{}"
#: The params file the stages read (dvc.yaml's default): the runs planned here are theirs.
PARAMS = "params.yaml"


def upstream_stages(repo, datasets: list[str]) -> list[str]:
    """The stages that produce what the datasets' train stages depend on, in dvc.yaml's order."""
    stages = list(repo.index.stages)
    train = {s.addressing: s for s in stages}
    missing = [TRAIN_STAGE.format(d) for d in datasets if TRAIN_STAGE.format(d) not in train]
    if missing:
        raise ParamsError(f"dvc.yaml: no stage {', '.join(missing)} (dataset_ids and dvc.yaml's train matrix differ)")
    needed = {str(Path(dep.def_path)) for d in datasets for dep in train[TRAIN_STAGE.format(d)].deps}
    return [s.addressing for s in stages if any(str(Path(out.def_path)) in needed for out in s.outs)]


def _dvc(*args: str) -> None:
    """``dvc <args>`` as a user would run it (its output shown); its failure is this command's."""
    cmd = [sys.executable, "-m", "dvc", *args]
    log.info("%s", " ".join(["dvc", *args]))
    if subprocess.run(cmd).returncode != 0:
        raise RunError(f"dvc {' '.join(args)}: failed (its output above)")


def train_everything(params, repo) -> int:
    """Step 2: every dataset's unfinished runs as one submission, under DVC's repository lock;
    the number of runs handed out."""
    from dvc.lock import LockError

    runs = [r for d in params.dataset_ids for r in dataset_runs(params, d)]
    try:
        with repo.lock:
            finished = finished_runs(params, runs)
            todo = [r for r in runs if r.name not in finished]
            log.info("%d runs of %d datasets: %d complete, %d to train", len(runs), len(params.dataset_ids),
                     len(finished), len(todo))
            if todo:
                train_todo(params, todo, "train all", chosen_executor())
    except LockError:
        raise RunError(f"{repo.lock.lockfile}: another dvc command holds this checkout's lock; "
                       "run this when it has ended") from None
    return len(todo)


@stage
def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--no-repro", action="store_true", help="submit and wait only; a later dvc repro finds the runs done")
    args = ap.parse_args(argv)
    params = start(PARAMS, workers=("train.parallel_runs", "train.num_workers"), device=True)  # DVC's params file
    from dvc.exceptions import DvcException, NotDvcRepoError
    from dvc.repo import Repo

    try:
        check_weightings(params, PARAMS)
        chosen_executor()  # a bad executor setting, before any stage runs
        with Repo(".") as repo:
            _dvc("repro", *upstream_stages(repo, list(params.dataset_ids)))
            handed = train_everything(params, repo)
        log.info("%d runs trained in one submission", handed)
        if not args.no_repro:
            _dvc("repro")
    except (JobError, RunError, CacheError, ParamsError, SettingsError) as err:
        sys.exit(f"error: {err}")
    except NotDvcRepoError:
        sys.exit(f"error: {Path.cwd()}: not a DVC repository; run this from the project's root")
    except DvcException as err:
        sys.exit(f"error: dvc: {' '.join(str(err).split())[:300]}")
    except OSError as err:
        sys.exit(f"error: {os_error_line(err, Path('runs'))}")


if __name__ == "__main__":
    main()
