"""Run one dataset's runs at ``scale: full`` in a scratch copy of the repository, and record them.

    .venv/bin/python benchmarks/record_full.py --dataset B --part compact \
        --models compact_1l compact_15l compact_15l_mgn compact_15l_mgn_authors --workdir /tmp/full_B
    .venv/bin/python benchmarks/record_full.py --dataset B --root DIR --part compact ...   # record only
    .venv/bin/python benchmarks/record_full.py --dataset A --part study_uw_dwa --arms uw dwa \
        --commit C --workdir /tmp/full_A                  # loss-balancing study arms (see below)

Run mode (``--workdir``): clones this repository at ``--commit`` (default ``HEAD``) into the
work folder, or reuses a clone already there at that commit (a stopped part resumes: each run
starts again from its ``last.pt``); sets its params.yaml to ``scale: full``, this dataset and the
models (and, with ``--seeds``, those seeds only) and no arm of the loss-balancing study (which set
A's train stage would otherwise train beside them), through DVC's own YAML writer; creates its
``.venv`` (``make setup``) and runs the pipeline's own stages, ``dvc repro train@<ds>
evaluate@<ds>`` (the data stages before them as DVC needs), logging to ``<workdir>/record_full.log``.
The copy's params.yaml is that commit's: one written in a layout since replaced is read in today's
(``core/params/former.py`` lists those layouts), so a run recorded at an earlier commit is re-created
by the command its record gives.
Then, or with ``--root DIR`` alone, it writes the record (version 2 of
``compact_perception.core.plateau_record``, the one record format, which the report reads with):
per run its ``summary.json``, ``metrics.json``, ``per_frame.csv`` and loss-weight and validation
series whole, and every params value that shaped it; the dataset's floor and cache meta; the
commit, the machine (CPU family and model) and the command that re-creates the part, and per run
the command that re-creates that run alone. A run that failed or did not finish is recorded as
``incomplete``, with no number. ``--check RECORD`` compares the runs just recorded with the same
runs of an earlier record and exits 1 unless every recorded number is equal.

``--parallel-runs N`` sets ``train.parallel_runs`` in the copy: how many runs train side by side
(the stage lowers it to the usable cores), which changes no number (each run keeps its
``train.num_threads``; the record's settings leave it out). The commit's params say 2, for 2 cores;
on a machine with more, a part's runs train at once with ``--parallel-runs`` set to their count.

A study part (``--arms``) trains and records arms of the loss-balancing study (params ``study``)
on the dataset: the copy's params run the study there with these arms alone, and as its models
``study.base_model`` alone, whose runs the arms are compared with and which the params need. Those
base runs are not recorded (the dataset's compact record holds them): run the part in the clone
(``--workdir``, same ``--commit``) where the compact part trained them, and the train stage skips
them as complete; in a fresh clone they train first. Each arm's run is recorded with its ``arm``.

Bad input is one line ``error: ...``, exit status 1; nothing is written where the record cannot be
complete, and the file at ``--out`` is replaced atomically.
"""
from __future__ import annotations

import argparse
import logging
import os
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from compact_perception.core import io  # noqa: E402
from compact_perception.core.catalog import MODELS  # noqa: E402
from compact_perception.core.params import Params, ParamsError, load_params  # noqa: E402
from compact_perception.core.errors import ReportInputError  # noqa: E402
from compact_perception.core.plateau_record import (STATUS_COMPLETE, record_problem, record_runs,  # noqa: E402
                                                    run_name)

log = logging.getLogger("record_full")
#: What a run's record is compared on by ``--check`` (the numbers the pipeline computed).
CHECKED = ("metrics", "per_frame", "curves", "epochs_run", "best_epoch", "stop_reason", "floor_margin")


class RecordError(Exception):
    """A failure of this script, in one line."""


def machine() -> str:
    """The CPU as /proc/cpuinfo names it (model name, family, model) and the usable cores."""
    fields: dict[str, str] = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    name = fields.get("model name", "unknown CPU")
    family = f" (family {fields['cpu family']} model {fields['model']})" if "cpu family" in fields else ""
    return f"{name}{family}, {len(os.sched_getaffinity(0))} cores"


def _git(root: Path, *args: str) -> str:
    try:
        return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError) as err:
        raise RecordError(f"{root}: git {' '.join(args)} failed ({getattr(err, 'stderr', '') or err})".strip()) from None


def commit_of(root: Path) -> str:
    try:
        return _git(root, "describe", "--always", "--dirty", "--abbrev=12")
    except RecordError:
        return "not a git checkout"


def prepare(workdir: Path, commit: str) -> str:
    """A clone of this repository at ``commit`` in ``workdir`` (made, or found there at that
    commit); returns the full commit id."""
    want = _git(ROOT, "rev-parse", "--verify", f"{commit}^{{commit}}")
    if workdir.exists() and any(workdir.iterdir()):
        if not (workdir / ".git").exists():
            raise RecordError(f"{workdir}: not empty and not a clone of this repository")
        have = _git(workdir, "rev-parse", "HEAD")
        if have != want:
            raise RecordError(f"{workdir}: a clone at {have[:12]}, not {want[:12]}: use another --workdir")
        return want
    workdir.parent.mkdir(parents=True, exist_ok=True)
    _git(ROOT.parent, "clone", "--quiet", str(ROOT), str(workdir))
    _git(workdir, "checkout", "--quiet", want)
    return want


def set_params(path: Path, dataset: str, models: list[str], seeds: list[int] | None,
               arms: list[str] | None = None, parallel_runs: int | None = None) -> Params:
    """``scale: full``, this dataset, these models (and seeds) and no study arm in the copy's
    params.yaml, written by DVC's own YAML writer (comments and order kept); returns them validated.
    With ``arms`` (a study part): the study on this dataset with these arms alone, and
    ``study.base_model`` as the only model (``models`` is not used). ``parallel_runs``, if given, is
    ``train.parallel_runs``."""
    from dvc.utils.serialize import modify_yaml  # the writer `dvc exp run -S` uses

    with modify_yaml(path) as data:
        data["scale"] = "full"
        data["dataset_ids"] = [dataset]
        if dataset in data["sim_ids"]:
            data["sim_ids"] = [dataset]
        # the loss-balancing study trains in the same train stage (set A at full): a part's runs
        # are its models' or, for a study part, its arms' (beside the base model, which they need)
        study = data["study"]["datasets"]
        data["study"]["datasets"] = {**study, "full": [dataset] if arms else []} if isinstance(study, dict) else []
        data["model_ids"] = [data["study"]["base_model"]] if arms else models
        if arms:
            data["study"]["arm_ids"] = list(arms)
            data["study"]["arms"] = {a: data["study"]["arms"][a] for a in arms}
        if seeds is not None:
            data["baseline_seeds"]["full"] = seeds
            data["datasets"][dataset]["training"]["seeds"]["full"] = seeds
        if parallel_runs is not None:
            data["train"]["parallel_runs"] = parallel_runs
    return load_params(path, former=True)


def _check_arms(arms: list[str] | None, params: Params, path: Path) -> None:
    """Each of ``arms`` is an arm of the params' study (one line naming the file otherwise)."""
    unknown = [a for a in arms or () if a not in params.study.arms]
    if unknown or len(set(arms or ())) != len(arms or ()):
        raise ParamsError(f"--arms: expected distinct arms of study.arms in {path} "
                          f"({', '.join(params.study.arm_ids)}) (got {arms})")


def run_stages(workdir: Path, dataset: str) -> int:
    """``make setup`` and ``dvc repro train@<ds> evaluate@<ds>`` in the copy, logged; the exit status."""
    env = {**os.environ, "PATH": f"{workdir / '.venv' / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}",
           "DVC_NO_ANALYTICS": "1"}
    logfile = workdir / "record_full.log"
    with open(logfile, "ab") as out:
        for cmd in (["make", "-s", "setup"], ["dvc", "repro", f"train@{dataset}", f"evaluate@{dataset}"]):
            log.info("%s: %s (log: %s)", workdir, " ".join(cmd), logfile)
            rc = subprocess.run(cmd, cwd=workdir, env=env, stdout=out, stderr=subprocess.STDOUT).returncode
            if rc:
                log.warning("%s exited %d: runs not finished are recorded as incomplete", " ".join(cmd), rc)
                return rc
    return 0


def compare(new: dict, old_path: Path) -> list[str]:
    """What differs between the complete runs of ``new`` and the same runs of the record at ``old_path``."""
    old = io.read_json(old_path)
    problem = record_problem(old)
    if problem:
        raise RecordError(f"{old_path}: {problem}")
    before = {(run_name(r), r["seed"]): r for r in old["runs"] if r.get("status") == STATUS_COMPLETE}
    diffs = []
    for run in new["runs"]:
        key = (run_name(run), run["seed"])
        if run.get("status") != STATUS_COMPLETE:
            diffs.append(f"{key[0]} seed {key[1]}: not complete here")
        elif key not in before:
            diffs.append(f"{key[0]} seed {key[1]}: not in {old_path}")
        else:
            diffs += [f"{key[0]} seed {key[1]}: {k} differs" for k in CHECKED if run.get(k) != before[key].get(k)]
    return diffs


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", required=True, help="the dataset id (params dataset_ids)")
    ap.add_argument("--part", default=None, help="the part's name, in the record's file name (default: all)")
    what = ap.add_mutually_exclusive_group()
    what.add_argument("--models", nargs="+", help="model ids (default: the copy's model_ids)")
    what.add_argument("--arms", nargs="+", help="a study part: these arms of the loss-balancing study (params "
                                                "study.arm_ids), on study.base_model")
    ap.add_argument("--seeds", nargs="+", type=int, help="only these seeds (default: the params' at full)")
    where = ap.add_mutually_exclusive_group(required=True)
    where.add_argument("--workdir", type=Path, help="run: the scratch clone to run the stages in")
    where.add_argument("--root", type=Path, help="record only: a copy whose stages have run")
    ap.add_argument("--parallel-runs", type=int, help="run: train.parallel_runs in the copy (runs side by side; "
                                                       "changes no number)")
    ap.add_argument("--commit", default="HEAD", help="run: the code to run (default HEAD)")
    ap.add_argument("--machine", help="where they ran (default: this machine's CPU)")
    ap.add_argument("--out", type=Path, help="the record (default benchmarks/records/full/<ds>[_<part>].json)")
    ap.add_argument("--check", type=Path, help="an earlier record: exit 1 unless these runs' numbers equal its")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> None:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    args = parse_args(argv)
    out = args.out or ROOT / "benchmarks" / "records" / "full" / f"{args.dataset}{'_' + args.part if args.part else ''}.json"
    try:
        if args.seeds is not None and any(s < 0 for s in args.seeds):
            raise RecordError(f"--seeds: expected integers of at least 0 (got {args.seeds})")
        if args.parallel_runs is not None and args.parallel_runs < 1:
            raise RecordError(f"--parallel-runs: expected an integer of at least 1 (got {args.parallel_runs})")
        if args.part is not None and not (args.part.replace("_", "").isalnum() and len(args.part) <= 40):
            raise RecordError(f"--part: expected a short name of letters, digits and _ (got {args.part[:60]!r})")
        root = args.workdir or args.root
        if args.workdir:
            commit = prepare(args.workdir.resolve(), args.commit)
            before = load_params(args.workdir / "params.yaml", former=True)
            _check_arms(args.arms, before, args.workdir / "params.yaml")
            models = args.models or list(before.model_ids)
            params = set_params(args.workdir / "params.yaml", args.dataset, models, args.seeds, args.arms,
                                args.parallel_runs)
        else:
            params = load_params(root / "params.yaml", former=True)
            _check_arms(args.arms, params, root / "params.yaml")
        models = [] if args.arms else (args.models or list(params.model_ids))
        unknown = [m for m in models if m not in MODELS or m not in params.train.models]
        if unknown:
            raise ParamsError(f"--models: {unknown} not models of {root / 'params.yaml'}")
        if args.dataset not in params.dataset_ids:
            raise ParamsError(f"--dataset: {args.dataset!r} not in dataset_ids of {root / 'params.yaml'}")
        rc = run_stages(args.workdir, args.dataset) if args.workdir else 0
        commit = commit if args.workdir else commit_of(root)
        seeds = {m: list(params.seeds_of(MODELS[m].group, args.dataset)) for m in models}
        base_seeds = list(params.seeds_of(MODELS[params.study.base_model].group, args.dataset))
        arms = {a: base_seeds for a in args.arms or ()}
        base = ["python", "benchmarks/record_full.py", "--dataset", args.dataset, "--commit", commit[:12]]
        part_cmd = base + [*(["--part", args.part] if args.part else []),
                           *(["--arms", *args.arms] if args.arms else ["--models", *models]),
                           *(["--seeds", *map(str, args.seeds)] if args.seeds else []),
                           *(["--parallel-runs", str(args.parallel_runs)] if args.parallel_runs else []),
                           "--workdir", "<scratch folder>"]
        provenance = {"commit": commit, "machine": args.machine or machine(),
                      "command": shlex.join(part_cmd) + (f" (stages exited {rc})" if rc else "")}
        record = record_runs(root, params, args.dataset, seeds, provenance, arms=arms,
                             run_command=lambda m, k, arm: shlex.join(
                                 base + (["--arms", arm] if arm else ["--models", m]) + [
                                     "--seeds", str(k), "--workdir", "<scratch folder>", "--out", "<file>",
                                     "--check", f"benchmarks/records/full/{out.name}"]))
        diffs = compare(record, args.check) if args.check else []
    except (ParamsError, ReportInputError, RecordError) as err:
        sys.exit(f"error: {err}")
    try:
        io.write_json(out, record)
    except OSError as err:
        sys.exit(f"error: {out}: {err.strerror or err}")
    for r in record["runs"]:
        if r["status"] == STATUS_COMPLETE:
            log.info("%s/%s/seed%d: %s after %d epochs (best %d), margins %s", r["dataset"], run_name(r), r["seed"],
                     r["stop_reason"], r["epochs_run"], r["best_epoch"],
                     {k: round(v, 3) for k, v in r["floor_margin"].items()})
        else:
            log.warning("%s/%s/seed%d: incomplete (%s)", r["dataset"], run_name(r), r["seed"], r["reason"])
    log.info("wrote %s (%d runs)", out, len(record["runs"]))
    if args.check:
        if diffs:
            sys.exit("error: " + f"{args.check}: " + "; ".join(diffs[:5]) + (f" and {len(diffs) - 5} more" if len(diffs) > 5 else ""))
        log.info("every recorded number equals %s's", args.check)


if __name__ == "__main__":
    main()
