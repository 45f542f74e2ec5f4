"""Shared start-up of every stage (logging and validated params) and of its worker processes
(logging), and the check at a stage's end that the params it read are still those on disk
(:func:`stage`: DVC records the params file as it is when the stage ends)."""
from __future__ import annotations

import atexit
import functools
import logging
import sys
import time
from pathlib import Path
from typing import Any, Callable

from compact_perception.core.params import Params, ParamsError, load_params
from compact_perception.core.machine import bounded_counts_line, device_problem
from compact_perception.core.params.audit import audited


def start(params_path: str | Path = "params.yaml", workers: tuple[str, ...] = (), device: bool = False) -> Params:
    """Configure logging and return validated params; exit with the message on bad input.
    ``workers``: the worker counts the stage uses (one line is logged naming each the machine's
    cores lower, core.machine); ``device``: the stage runs on ``train.device``, checked here, once,
    before any worker process starts."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    t0, argv = time.perf_counter(), " ".join(sys.argv[1:])
    atexit.register(lambda: logging.getLogger("pipeline").info("stage %s [%s] took %.1f s",
                                                               Path(sys.argv[0]).stem, argv, time.perf_counter() - t0))
    try:
        text = Path(params_path).read_bytes()  # before it is parsed: a change after this is seen at the end
    except OSError:
        text = None  # load_params names the problem
    try:
        params = load_params(params_path)
    except ParamsError as err:
        sys.exit(f"error: {err}")
    _READ.append((Path(params_path), text, params))
    problem = device_problem(params.train.device) if device else None
    if problem:
        sys.exit(f"error: {params_path}: {problem}")
    line = bounded_counts_line(params, workers)
    if line:
        logging.getLogger("pipeline").warning("%s", line)
    return audited(params)


def worker_logging() -> None:
    """In a stage's worker process (:mod:`compact_perception.learning.training.parallel`): the stage's
    logging. The worker gets the stage's validated params and its runs pickled (audited like the
    stage's when the audit is on: core.params.audit), never a file to read again."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")


#: Every params file a :func:`start` of this process read: its path, its bytes then, the params.
_READ: list[tuple[Path, bytes | None, Params]] = []
#: The most changed keys a line names.
_SHOWN_KEYS = 3


def _leaves(value: Any, prefix: str = "") -> dict[str, Any]:
    """``{dotted key: value}`` of every leaf of a dumped params mapping."""
    if isinstance(value, dict) and value:
        return {k: v for key, sub in value.items()
                for k, v in _leaves(sub, f"{prefix}.{key}" if prefix else str(key)).items()}
    return {prefix: value}


def params_change(path: Path, text: bytes | None, params: Params) -> str | None:
    """What changed in the params file at ``path`` since a stage read ``text`` and validated it to
    ``params``: ``None`` where nothing did (its bytes, or the values they validate to: a comment),
    else a short phrase naming the changed keys."""
    try:
        now = path.read_bytes()
    except OSError as err:
        return f"it can no longer be read: {err.strerror or err}"
    if now == text:
        return None
    try:
        new = load_params(path)
    except ParamsError as err:
        return f"it no longer validates: {str(err)[:200]}"
    old_keys, new_keys = _leaves(params.model_dump()), _leaves(new.model_dump())
    changed = sorted(k for k in old_keys.keys() | new_keys.keys() if old_keys.get(k, ...) != new_keys.get(k, ...))
    if not changed:
        return None
    more = f" and {len(changed) - _SHOWN_KEYS} more" if len(changed) > _SHOWN_KEYS else ""
    return ", ".join(changed[:_SHOWN_KEYS]) + more


def stage(main: Callable[..., Any]) -> Callable[..., Any]:
    """A stage's ``main``: when it returns (its outputs written), the params file each :func:`start`
    of it read must still hold the values read at the start; else one line and exit status 1, so
    that DVC records nothing: ``dvc.lock`` would otherwise pair the new params with outputs of the
    old (and ``dvc status`` call them up to date). A stage that fails is not checked."""
    @functools.wraps(main)
    def checked(argv: list[str] | None = None) -> Any:
        first = len(_READ)
        try:
            result = main(argv)
            read = _READ[first:]
        finally:
            del _READ[first:]
        for path, text, params in read:
            change = params_change(path, text, params)
            if change:
                sys.exit(f"error: {path}: changed while the stage ran ({change}); run it again")
        return result
    return checked
