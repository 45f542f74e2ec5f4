"""Record runs trained to their plateau, for the report's line on whether the baselines learn.

    .venv/bin/python benchmarks/record_plateau.py --root DIR [--dataset A] [--models ID ...]
        [--commit TEXT] [--machine TEXT] [--out benchmarks/records/full_plateau.json]

DIR is a copy of this repository whose params.yaml is at the scale to record (``scale: full``)
and in which ``dvc repro train@<ds> evaluate@<ds>`` has finished for the models (default: its
``model_ids``) and their seeds (its seed lists). It writes, per run, how training stopped
(``summary.json``), the test margin over the floor per task (``metrics.json`` ``floor_margin``)
and every params value that shaped the run, resolved at that scale
(:func:`compact_perception.core.plateau_record.settings_at`), with the commit (``git describe
--always --dirty`` of DIR unless ``--commit`` says more), the machine and the command. The
``report`` stage reads the file (a dependency in dvc.yaml) and says which of today's settings
differ from a recorded run's. Every run is checked by type and range against the record's schema
(``compact_perception.core.plateau_record``, the one module that defines the record, which the
report reads with; this script imports nothing of the report) before anything is written: a
summary or metrics file that says otherwise is one line naming it and the field, exit status 1,
and the file at ``--out`` is left as it was.
"""
from __future__ import annotations

import argparse
import logging
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from compact_perception.core import io  # noqa: E402
from compact_perception.core.catalog import MODELS  # noqa: E402
from compact_perception.core.config import ParamsError, load_params  # noqa: E402
from compact_perception.core.errors import ReportInputError  # noqa: E402
from compact_perception.core.plateau_record import record_runs  # noqa: E402

log = logging.getLogger("record_plateau")


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


def commit_of(root: Path) -> str:
    try:
        out = subprocess.run(["git", "-C", str(root), "describe", "--always", "--dirty"], capture_output=True,
                             text=True, check=True)
        return out.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "not a git checkout"


def main(argv: list[str] | None = None) -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", required=True, type=Path, help="the repository copy that trained and evaluated the runs")
    ap.add_argument("--dataset", default="A")
    ap.add_argument("--models", nargs="+", help="model ids (default: the copy's model_ids)")
    ap.add_argument("--commit", help="the code the runs came from (default: git describe of --root)")
    ap.add_argument("--machine", help="where they ran (default: this machine's CPU)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "records" / "full_plateau.json")
    args = ap.parse_args(argv)
    try:
        params = load_params(args.root / "params.yaml")
        models = args.models or list(params.model_ids)
        unknown = [m for m in models if m not in MODELS or m not in params.train.models]
        if unknown:
            raise ParamsError(f"--models: {unknown} not models of {args.root / 'params.yaml'}")
        if args.dataset not in params.dataset_ids:
            raise ParamsError(f"--dataset: {args.dataset!r} not in dataset_ids of {args.root / 'params.yaml'}")
        seeds = {m: params.seeds_of(MODELS[m].group, args.dataset) for m in models}
        provenance = {"commit": args.commit or commit_of(args.root), "machine": args.machine or machine(),
                      "command": f"dvc repro train@{args.dataset} evaluate@{args.dataset} at scale: {params.scale}"}
        record = record_runs(args.root, params, args.dataset, seeds, provenance)
    except (ParamsError, ReportInputError) as err:
        sys.exit(f"error: {err}")
    runs = record["runs"]
    try:
        io.write_json(args.out, record)
    except OSError as err:
        sys.exit(f"error: {args.out}: {err.strerror or err}")
    for r in runs:
        log.info("%s/%s/seed%d: %s after %d epochs (best %d), margins %s", r["dataset"], r["model"], r["seed"],
                 r["stop_reason"], r["epochs_run"], r["best_epoch"],
                 {k: round(v, 3) for k, v in r["floor_margin"].items()})
    log.info("wrote %s (%d runs)", args.out, len(runs))


if __name__ == "__main__":
    main()
