"""Shared start-up of every stage (logging and validated params) and of its worker processes (logging)."""
from __future__ import annotations

import atexit
import logging
import sys
import time
from pathlib import Path

from compact_perception.core.config import Params, ParamsError, load_params
from compact_perception.core.machine import bounded_counts_line, device_problem
from compact_perception.core.params_audit import audited


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
        params = load_params(params_path)
    except ParamsError as err:
        sys.exit(f"error: {err}")
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
    stage's when the audit is on: core.params_audit), never a file to read again."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
