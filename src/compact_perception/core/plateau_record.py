"""The record of runs trained to their plateau (``benchmarks/records/full_plateau.json``): its one
definition, below both its writer (``benchmarks/record_plateau.py``: :func:`record_runs`) and its
reader (the report: :func:`compact_perception.report.plateau.load_record`), so neither imports the
other.

The record holds, per run (dataset, model, seed; a run of the loss-balancing study also its
``arm``, its model then ``study.base_model``): how it stopped (``epochs_run``, ``best_epoch``,
``max_epochs``, ``stop_reason``, ``train_seconds`` from ``summary.json``), its test-set margin
over the floor per task metric (``floor_margin`` of ``metrics.json``, positive = better than the
better trivial predictor), and the settings it was trained under (:func:`settings_at`); with the
scale, commit, machine and command that made it.

Its schema (:data:`RUN_KEYS`, :func:`run_problem`, :func:`record_problem`) says what each run and
the record itself must hold, by type and range: the writer checks every run before anything is
written, and the reader checks what it reads, so neither can accept what the other refuses. Each
check answers with the first problem as ``<field>: expected <what> (got <value>)``, the value
shown bounded.
"""
from __future__ import annotations

import csv
import io
import math
import re
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

from .catalog import DATASETS, MODELS, STOP_CAP, STOP_PLATEAU
from .errors import ReportInputError
from .floor_rule import FLOOR_PREDICTORS
from .io import read_json, write_json, write_text
from .layout import RunPaths, cache_dir, floor_paths, paths_of_run, study_run_name
from .params.base import SCALES, resolve_scale
from .params.errors import shown
from .params.former import RENAMED_KEYS, UNRECORDED_VALUES

__all__ = ["RECORD_VERSION", "RECORD_VERSIONS", "DEVICES", "RUN_KEYS", "SUMMARY_KEYS", "NEUTRAL_KEYS",
           "CUDA_ONLY_KEYS", "UNRECORDED_VALUES", "CACHE_META_ADDED", "CURVE_NAMES", "STATUS_COMPLETE",
           "STATUS_INCOMPLETE", "run_problem", "record_problem", "settings_at", "changed_keys", "record_runs",
           "same_cache", "write_tree", "run_name"]

RECORD_VERSION = 2
RECORD_VERSIONS = (1, 2)
#: Where a record's runs trained: a CPU, or a CUDA GPU (whose own settings a CPU run ignores).
DEVICES = ("cpu", "cuda")

#: The keys of a run that come from its ``summary.json``.
SUMMARY_KEYS: tuple[str, ...] = ("epochs_run", "best_epoch", "max_epochs", "stop_reason", "train_seconds")


def _int_at_least(lo: int) -> Callable[[Any], bool]:
    return lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= lo


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _margins(v: Any) -> bool:
    return isinstance(v, dict) and bool(v) and all(isinstance(k, str) and _finite(x) for k, x in v.items())


def _settings(v: Any) -> bool:
    return isinstance(v, dict) and all(isinstance(k, str) for k in v)


#: Each key of a run: the check its value must pass and what that means, in the error's words.
RUN_KEYS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "dataset": (lambda v: isinstance(v, str) and v in DATASETS, f"one of {sorted(DATASETS)}"),
    "model": (lambda v: isinstance(v, str) and v in MODELS, f"one of {sorted(MODELS)}"),
    "seed": (_int_at_least(0), "an integer of at least 0"),
    "epochs_run": (_int_at_least(1), "an integer of at least 1"),
    "best_epoch": (_int_at_least(0), "an integer of at least 0 (the best epoch, counted from 0)"),
    "max_epochs": (_int_at_least(1), "an integer of at least 1"),
    "stop_reason": (lambda v: v in (STOP_PLATEAU, STOP_CAP), f"{STOP_PLATEAU!r} or {STOP_CAP!r}"),
    "train_seconds": (lambda v: _finite(v) and v >= 0, "a finite number of at least 0"),
    "floor_margin": (_margins, "a non-empty mapping of metric name to a finite number"),
    "settings": (_settings, "a mapping of params key to value"),
}


#: A study arm's id as a record holds it (a key of params ``study.arms``).
ARM_PATTERN = re.compile(r"[a-z][a-z0-9_]{0,39}")


def run_name(run: Mapping[str, Any]) -> str:
    """A recorded run's model id, or ``study:<arm>`` for a run of the loss-balancing study."""
    return study_run_name(run["arm"]) if run.get("arm") is not None else str(run["model"])


def run_problem(run: Any, keys: tuple[str, ...] = tuple(RUN_KEYS)) -> Optional[str]:
    """The first problem of ``run`` (a record's run, or the part of one named by ``keys``) as
    ``<field>: expected ... (got ...)``; ``None`` when it holds what the record promises."""
    if not isinstance(run, Mapping):
        return f"expected a mapping of {', '.join(keys)} (got {shown(run)})"
    for key in keys:
        check, what = RUN_KEYS[key]
        if key not in run:
            return f"{key}: missing (expected {what})"
        if not check(run[key]):
            return f"{key}: expected {what} (got {shown(run[key])})"
    if {"best_epoch", "epochs_run"} <= set(keys) and run["best_epoch"] >= run["epochs_run"]:
        return f"best_epoch: expected below epochs_run ({run['epochs_run']}) (got {run['best_epoch']})"
    if {"epochs_run", "max_epochs"} <= set(keys) and run["epochs_run"] > run["max_epochs"]:
        return f"epochs_run: expected at most max_epochs ({run['max_epochs']}) (got {run['epochs_run']})"
    return None


# ----------------------------------------------------------------------------- what a run was trained under
#: Settings that change no result (the pipeline's promise: any worker, process or run count gives
#: the same bytes; which test frame a figure shows, how many predictions are saved).
NEUTRAL_KEYS: tuple[str, ...] = ("world.workers", "preprocess.workers", "train.num_workers", "train.parallel_runs",
                                 "train.cuda_graphs",  # a CPU never captures; a GPU only a step bit-equal to eager
                                 "evaluate.figure_frame", "evaluate.save_predictions")


#: Settings that act on a CUDA GPU only: a run recorded on a CPU is the same whatever they say.
CUDA_ONLY_KEYS: tuple[str, ...] = ("train.deterministic", "train.tf32")


def _today_name(key: str) -> str:
    for pattern, name in RENAMED_KEYS:
        if re.match(pattern, key):
            return re.sub(pattern, name, key)
    return key


def changed_keys(recorded: Mapping[str, Any], now: Mapping[str, Any], device: str) -> list[str]:
    """The settings keys whose value ``now`` differs from a run's ``recorded`` settings (added or
    removed keys included), sorted, leaving out what cannot change that run: on a ``cpu`` record
    the keys of :data:`CUDA_ONLY_KEYS`, and a key of :data:`UNRECORDED_VALUES` the record lacks
    whose value now is the one it was made at; a key of :data:`RENAMED_KEYS` is compared under its
    name today."""
    missing = object()
    recorded = {_today_name(k): v for k, v in recorded.items()}
    out = []
    for k in sorted(set(now) | set(recorded)):
        if device == "cpu" and k in CUDA_ONLY_KEYS:
            continue
        before = recorded.get(k, UNRECORDED_VALUES.get(k, missing))
        if now.get(k, missing) != before:
            out.append(k)
    return out


def _flatten(prefix: str, value: Any, out: dict[str, Any]) -> None:
    if isinstance(value, dict) and value:
        for k, v in value.items():
            _flatten(f"{prefix}.{k}", v, out)
    else:
        out[prefix] = value


def settings_at(params: Any, model: str, dataset: str, scale: str, arm: Optional[str] = None) -> dict[str, Any]:
    """Every params value that shapes a run of ``model`` on ``dataset`` at ``scale``, as dotted keys:
    the model's merged recipe (``train.models.<model>``; for study arm ``arm``, the arm's recipe,
    the base model's with the arm's weighting, as ``study.arms.<arm>``, and ``study.base_model``),
    its epoch cap (``max_epochs``: the recipe's own, else the dataset's), the other ``train`` keys, ``seed``, ``world``,
    ``preprocess``, ``evaluate`` and ``datasets.<dataset>`` (its seed list left out: a record keeps
    each run's seed; its ``source`` section holds its own source's settings only), less
    :data:`NEUTRAL_KEYS`. Read through the params' own sections (so a stage's params audit sees
    every key), each per-scale value taken at ``scale`` whatever the file's own ``scale``."""
    if scale not in SCALES:
        raise ValueError(f"scale {scale!r}: expected one of {list(SCALES)}")
    own = params.study_recipe(arm) if arm is not None else params.train.models[model]
    recipe = resolve_scale(own.model_dump(mode="json", exclude_none=True), scale)
    section = resolve_scale(params.dataset(dataset).model_dump(mode="json"), scale)
    section.get("training", {}).pop("seeds", None)
    out: dict[str, Any] = {"seed": params.seed, "max_epochs": params.max_epochs_of(own, dataset, scale)}
    if arm is not None:
        out["study.base_model"] = params.study.base_model
    _flatten(f"study.arms.{arm}" if arm is not None else f"train.models.{model}", recipe, out)
    _flatten("train", resolve_scale(params.train.model_dump(mode="json", exclude={"models", "recipe"}), scale), out)
    for name in ("world", "preprocess", "evaluate"):
        _flatten(name, resolve_scale(getattr(params, name).model_dump(mode="json"), scale), out)
    _flatten(f"datasets.{dataset}", section, out)
    return {k: v for k, v in sorted(out.items()) if k not in NEUTRAL_KEYS}


# ----------------------------------------------------------------------------- a run's files in a record
#: The dvclive series a record keeps of a run (``live/plots/metrics/<name>.tsv``): the loss
#: weights per epoch (Fig. 8, the mgn-weights claim), the validation curve and the learning rate.
CURVE_NAMES: tuple[str, ...] = ("w_de", "w_ss", "w_ls", "w_bevp", "val_score", "val/tm", "lr")
#: The bounds a record's text and tables keep (a record is read by the report: nothing unbounded).
MAX_TEXT = 500
MAX_ROWS = 100_000


def _table_problem(v: Any) -> Optional[str]:
    """What is wrong with a per-frame table ``{"columns": [...], "rows": [[...], ...]}`` (``None``: sound)."""
    if not isinstance(v, Mapping) or set(v) != {"columns", "rows"}:
        return f"expected {{'columns': [...], 'rows': [...]}} (got {shown(v)})"
    cols, rows = v["columns"], v["rows"]
    if not (isinstance(cols, list) and cols and cols[0] == "frame_id" and all(isinstance(c, str) for c in cols)
            and len(set(cols)) == len(cols)):
        return f"columns: expected distinct names, 'frame_id' first (got {shown(cols)})"
    if not isinstance(rows, list) or not rows or len(rows) > MAX_ROWS:
        return f"rows: expected 1 to {MAX_ROWS} rows (got {shown(rows)})"
    for i, row in enumerate(rows):
        if not (isinstance(row, list) and len(row) == len(cols) and isinstance(row[0], str)
                and all(c is None or _finite(c) for c in row[1:])):
            return f"rows[{i}]: expected a frame id and {len(cols) - 1} finite numbers or null (got {shown(row)})"
    return None


def _curves_problem(v: Any) -> Optional[str]:
    if not isinstance(v, Mapping):
        return f"expected a mapping of series name to [[step, value], ...] (got {shown(v)})"
    for name, series in v.items():
        if name not in CURVE_NAMES:
            return f"{name}: expected one of {list(CURVE_NAMES)}"
        if not (isinstance(series, list) and len(series) <= MAX_ROWS and all(
                isinstance(p, list) and len(p) == 2 and _int_at_least(0)(p[0]) and _finite(p[1]) for p in series)):
            return f"{name}: expected [[step, finite value], ...] (got {shown(series)})"
    return None


def _text(v: Any) -> bool:
    return isinstance(v, str) and len(v) <= MAX_TEXT and v.isprintable()


#: What a version-2 run holds beyond :data:`RUN_KEYS`: its files, whole (``metrics.json``,
#: ``per_frame.csv`` as a table, ``summary.json``, the dvclive series of :data:`CURVE_NAMES`) and
#: the command that re-creates it. Each check answers with the problem or ``None``.
FILE_KEYS: dict[str, Callable[[Any], Optional[str]]] = {
    "metrics": lambda v: None if isinstance(v, Mapping) and isinstance(v.get("floor_margin"), Mapping)
    else f"expected metrics.json's object with its floor_margin (got {shown(v)})",
    "per_frame": _table_problem,
    "summary": lambda v: None if isinstance(v, Mapping) else f"expected summary.json's object (got {shown(v)})",
    "curves": _curves_problem,
    "command": lambda v: None if _text(v) else f"expected one line of at most {MAX_TEXT} characters (got {shown(v)})",
}
#: A run of a version-2 record is ``complete`` (trained and evaluated: every key) or
#: ``incomplete`` (a run that failed or was stopped: ``reason`` says what was found, no number).
STATUS_COMPLETE, STATUS_INCOMPLETE = "complete", "incomplete"


def _v2_run_problem(run: Mapping[str, Any]) -> Optional[str]:
    arm = run.get("arm")
    if arm is not None and not (isinstance(arm, str) and ARM_PATTERN.fullmatch(arm)):
        return f"arm: expected a study arm's id (letters, digits and _) or null (got {shown(arm)})"
    status = run.get("status")
    if status == STATUS_INCOMPLETE:
        for key in ("dataset", "model", "seed", "settings"):
            problem = run_problem(run, (key,))
            if problem:
                return problem
        if not _text(run.get("reason")):
            return f"reason: expected one line of at most {MAX_TEXT} characters (got {shown(run.get('reason'))})"
        extra = sorted(set(run) - {"dataset", "model", "seed", "arm", "settings", "status", "reason", "command"})
        return f"{extra[0]}: an incomplete run records no number" if extra else None
    if status != STATUS_COMPLETE:
        return f"status: expected {STATUS_COMPLETE!r} or {STATUS_INCOMPLETE!r} (got {shown(status)})"
    problem = run_problem(run)
    if problem:
        return problem
    for key, check in FILE_KEYS.items():
        if key not in run:
            return f"{key}: missing"
        problem = check(run[key])
        if problem:
            return f"{key}: {problem}"
    return None


def _floor_problem(v: Any) -> Optional[str]:
    if not isinstance(v, Mapping) or not v:
        return f"expected a mapping of trivial predictor id to its metrics and per_frame (got {shown(v)})"
    for tid, entry in v.items():
        if tid not in FLOOR_PREDICTORS:
            return f"{tid}: expected one of {list(FLOOR_PREDICTORS)}"
        if not isinstance(entry, Mapping) or set(entry) != {"metrics", "per_frame"} or not isinstance(
                entry["metrics"], Mapping):
            return f"{tid}: expected {{'metrics': {{...}}, 'per_frame': {{...}}}} (got {shown(entry)})"
        problem = _table_problem(entry["per_frame"])
        if problem:
            return f"{tid}.per_frame: {problem}"
    return None


def record_problem(data: Any) -> Optional[str]:
    """The first problem of a whole record (its version, scale, provenance and every run), the
    run named by its index (``runs[2].epochs_run: ...``); ``None`` for a sound record. Version 1
    (the first record, of runs' stopping and margins only) is read as it was written."""
    if not isinstance(data, Mapping):
        return f"expected a JSON object (got {shown(data)})"
    version = data.get("version")
    if version not in RECORD_VERSIONS:
        return f"version: expected one of {list(RECORD_VERSIONS)} (got {shown(version)})"
    if data.get("scale") not in SCALES:
        return f"scale: expected one of {list(SCALES)} (got {shown(data.get('scale'))})"
    for key in ("commit", "machine", "command"):
        if not _text(data.get(key, "")):
            return f"{key}: expected one line of at most {MAX_TEXT} characters (got {shown(data[key])})"
    if not isinstance(data.get("runs"), list):
        return f"runs: expected a list (got {shown(data.get('runs'))})"
    if version == 2:
        if data.get("dataset") not in DATASETS:
            return f"dataset: expected one of {sorted(DATASETS)} (got {shown(data.get('dataset'))})"
        if data.get("device") not in DEVICES:
            return f"device: expected one of {list(DEVICES)} (got {shown(data.get('device'))})"
        if not isinstance(data.get("cache_meta"), Mapping):
            return f"cache_meta: expected data/cache/<ds>/meta.json's object (got {shown(data.get('cache_meta'))})"
        problem = _floor_problem(data.get("floor"))
        if problem:
            return f"floor: {problem}"
    seen = set()
    for i, run in enumerate(data["runs"]):
        problem = (run_problem(run) if version == 1 or not isinstance(run, Mapping) else _v2_run_problem(run))
        if problem:
            return f"runs[{i}]" + ("." if isinstance(run, Mapping) else ": ") + problem
        if version == 2 and run["dataset"] != data["dataset"]:
            return f"runs[{i}].dataset: expected the record's {data['dataset']!r} (got {shown(run['dataset'])})"
        key = (run["dataset"], run_name(run), run["seed"])
        if key in seen:
            return f"runs[{i}]: {key[1]} seed {key[2]} recorded twice"
        seen.add(key)
    return None


def _per_frame_table(path: Path) -> dict[str, Any]:
    """``per_frame.csv`` as ``{"columns", "rows"}``: the frame id as text, every score as the
    number its text gives (Python's float of it: the file's numbers, exactly) or ``None`` if empty."""
    try:
        with open(path, newline="", encoding="utf-8") as f:
            rows = list(csv.reader(f))
    except FileNotFoundError:
        raise ReportInputError(f"{path}: missing") from None
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise ReportInputError(f"{path}: unreadable ({err})") from None
    if not rows:
        raise ReportInputError(f"{path}: empty")
    cols, body = rows[0], rows[1:]
    try:
        table = {"columns": cols, "rows": [[r[0], *(float(x) if x != "" else None for x in r[1:])] for r in body]}
    except (ValueError, IndexError) as err:
        raise ReportInputError(f"{path}: expected a frame id and numbers per row ({err})") from None
    problem = _table_problem(table)
    if problem:
        raise ReportInputError(f"{path}: {problem}")
    return table


def _write_per_frame(path: Path, table: Mapping[str, Any]) -> None:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(table["columns"])
    for row in table["rows"]:
        w.writerow(["" if x is None else (repr(float(x)) if not isinstance(x, str) else x) for x in row])
    write_text(path, buf.getvalue())


def _curves(live: Path) -> dict[str, list[list[Any]]]:
    out: dict[str, list[list[Any]]] = {}
    for name in CURVE_NAMES:
        path = live / "plots" / "metrics" / f"{name}.tsv"
        if not path.is_file():
            continue
        try:
            with open(path, newline="", encoding="utf-8") as f:
                rows = list(csv.reader(f, delimiter="\t"))
            col = rows[0].index(name.rsplit("/", 1)[-1])
            out[name] = [[int(r[rows[0].index("step")]), float(r[col])] for r in rows[1:]]
        except (OSError, ValueError, IndexError, UnicodeDecodeError) as err:
            raise ReportInputError(f"{path}: expected columns step and {name.rsplit('/', 1)[-1]} ({err})") from None
    return out


def _write_curves(live: Path, curves: Mapping[str, Sequence[Sequence[Any]]]) -> None:
    for name, series in curves.items():
        col = name.rsplit("/", 1)[-1]
        write_text(live / "plots" / "metrics" / f"{name}.tsv",
                   f"step\t{col}\n" + "".join(f"{int(s)}\t{float(v)!r}\n" for s, v in series))


# ----------------------------------------------------------------------------- the writer
def _record_run(root: Path, dataset: str, model: str, seed: int, arm: Optional[str], paths: RunPaths,
                settings: dict[str, Any], command: str) -> dict[str, Any]:
    """One run's entry: ``complete`` with its files whole, or ``incomplete`` with what was found."""
    ident = {"dataset": dataset, "model": model, "seed": int(seed), **({"arm": arm} if arm is not None else {})}
    files = {"summary": paths.run_dir / "summary.json", "metrics": paths.metrics_path,
             "per_frame": paths.eval_dir / "per_frame.csv"}
    absent = [str(p.relative_to(root)) for p in files.values() if not p.is_file()]
    if absent:
        what = "no run folder" if not paths.run_dir.is_dir() else (
            "stopped before it finished (last.pt only)" if paths.run_dir.joinpath("last.pt").is_file()
            else "no checkpoint")
        return {**ident, "status": STATUS_INCOMPLETE, "settings": settings, "command": command,
                "reason": f"{what}; missing {', '.join(absent)}"[:MAX_TEXT]}
    summ, metrics = read_json(files["summary"]), read_json(files["metrics"])
    missing = [k for k in SUMMARY_KEYS if summ.get(k) is None]
    if missing:
        raise ReportInputError(f"{files['summary']}: missing {', '.join(missing)}")
    if not isinstance(metrics.get("floor_margin"), dict):
        raise ReportInputError(f"{files['metrics']}: no floor_margin (evaluate the run with its floor first)")
    for path, data, keys in ((files["summary"], summ, SUMMARY_KEYS), (files["metrics"], metrics, ("floor_margin",))):
        problem = run_problem(data, keys)
        if problem:
            raise ReportInputError(f"{path}: {problem}")
    return {**ident, "status": STATUS_COMPLETE, **{k: summ[k] for k in SUMMARY_KEYS},
            "floor_margin": {k: float(v) for k, v in sorted(metrics["floor_margin"].items())},
            "settings": settings, "metrics": metrics, "per_frame": _per_frame_table(files["per_frame"]),
            "summary": summ, "curves": _curves(paths.live), "command": command}


def record_runs(root: Path, params: Any, dataset: str, seeds: Mapping[str, Sequence[int]],
                provenance: Mapping[str, str], run_command: Optional[Callable[[str, int, Optional[str]], str]] = None,
                device: str = "cpu", arms: Optional[Mapping[str, Sequence[int]]] = None) -> dict[str, Any]:
    """The record (version 2) of the runs under ``root`` of each model of ``seeds`` and its seeds
    on ``dataset``, and of each study arm of ``arms`` and its seeds (``runs/<ds>/study/<arm>/``:
    recorded with ``arm``, its model ``study.base_model``), trained with ``params`` (its own
    ``scale``); ``provenance``: ``commit``, ``machine``, ``command`` (the record's);
    ``run_command(model, seed, arm)``: the command that re-creates one run (``arm`` ``None`` but
    for a study arm's); ``device``: where they ran (``cpu`` or ``cuda``).

    A run is ``complete`` when its ``summary.json``, ``metrics.json`` and ``per_frame.csv`` exist:
    it is recorded with those files whole and its dvclive series (:data:`CURVE_NAMES`); any other
    run is ``incomplete``, with what was found and no number. The floor's trivial predictors
    (``results/<ds>/<id>/metrics.json``, ``data/eval/<ds>/<id>/per_frame.csv``) and the cache's
    ``meta.json`` are recorded once. Everything is checked against the record's schema (the one
    the report's reader checks with) before it is returned: a file that says otherwise raises
    :class:`~.errors.ReportInputError` naming it and the field, so nothing is written."""
    planned: list[tuple[str, Optional[str], Sequence[int]]] = [(m, None, k) for m, k in seeds.items()]
    planned += [(params.study.base_model, arm, k) for arm, k in (arms or {}).items()]
    runs = []
    for model, arm, model_seeds in planned:
        settings = settings_at(params, model, dataset, params.scale, arm)
        for seed in model_seeds:
            paths = paths_of_run(dataset, model, seed, arm, root)
            command = run_command(model, int(seed), arm) if run_command else ""
            runs.append(_record_run(root, dataset, model, seed, arm, paths, settings, command))
    floor = {}
    for tid in FLOOR_PREDICTORS:
        fp = floor_paths(dataset, tid, root)
        if fp.metrics_path.is_file():
            floor[tid] = {"metrics": read_json(fp.metrics_path), "per_frame": _per_frame_table(fp.eval_dir / "per_frame.csv")}
    record = {"version": RECORD_VERSION, "scale": params.scale, "dataset": dataset, "device": device,
              **{k: str(provenance.get(k, "")) for k in ("commit", "machine", "command")},
              "cache_meta": read_json(cache_dir(dataset, root) / "meta.json"), "floor": floor, "runs": runs}
    problem = record_problem(record)
    if problem:  # the whole record passes the reader's check too (its seeds, settings and provenance)
        raise ReportInputError(f"{root}: {problem}")
    return record


# ----------------------------------------------------------------------------- the record as a run tree
#: Keys a cache's ``meta.json`` gained after runs were recorded (``sha256``, each cache file's
#: hash): a record made before holds every other key of the same cache.
CACHE_META_ADDED: tuple[str, ...] = ("sha256",)


def same_cache(a: Mapping[str, Any], b: Mapping[str, Any]) -> bool:
    """Whether two records' cache metas describe one cache: equal on every key, but for a key of
    :data:`CACHE_META_ADDED` that one of them lacks (it was recorded before the key existed)."""
    def kept(meta: Mapping[str, Any], other: Mapping[str, Any]) -> dict:
        return {k: v for k, v in meta.items() if k not in CACHE_META_ADDED or k in other}
    return kept(a, b) == kept(b, a)


def write_tree(record: Mapping[str, Any], root: Path) -> list[tuple[str, int, Optional[str]]]:
    """Write what a version-2 record holds as the files the pipeline wrote, under ``root`` in the
    pipeline's layout (:mod:`.layout`): each complete run's ``summary.json``, dvclive series,
    ``metrics.json`` and ``per_frame.csv``, the floor's files and the cache's ``meta.json``, so
    the report reads a record with the code it reads a run tree with (a study arm's run under
    ``runs/<ds>/study/<arm>/``). Returns the (model, seed, arm) of the runs written (``arm``
    ``None`` but for a study arm's). Two records of one dataset (its compact runs, its baselines) go into one
    tree: their floors and caches must agree (:func:`same_cache`; the tree keeps the meta that
    holds the most), else :class:`~.errors.ReportInputError`."""
    ds = record["dataset"]
    meta_path = cache_dir(ds, root) / "meta.json"
    meta = dict(record["cache_meta"])
    if meta_path.is_file():
        before = read_json(meta_path)
        if not same_cache(before, meta):
            raise ReportInputError(f"{ds}: the records' caches differ (data/cache/{ds}/meta.json): one dataset, one cache")
        meta = {**before, **meta}
    write_json(meta_path, meta)
    for tid, entry in record["floor"].items():
        fp = floor_paths(ds, tid, root)
        if fp.metrics_path.is_file() and read_json(fp.metrics_path) != entry["metrics"]:
            raise ReportInputError(f"{ds}: the records' floors differ ({tid}): one dataset, one floor")
        write_json(fp.metrics_path, entry["metrics"])
        _write_per_frame(fp.eval_dir / "per_frame.csv", entry["per_frame"])
    written: list[tuple[str, int, Optional[str]]] = []
    for run in record["runs"]:
        if run.get("status") != STATUS_COMPLETE:
            continue
        arm = run.get("arm")
        paths = paths_of_run(ds, run["model"], run["seed"], arm, root)
        write_json(paths.run_dir / "summary.json", run["summary"])
        _write_curves(paths.live, run["curves"])
        write_json(paths.metrics_path, run["metrics"])
        _write_per_frame(paths.eval_dir / "per_frame.csv", run["per_frame"])
        written.append((run["model"], run["seed"], arm))
    return written
