"""The benchmark scripts' flags, checked as the pipeline checks its inputs: a bad value is one line,
``error: --flag: <what was expected> (got <value>)``, and exit status 1, before any work starts
(not argparse's usage block and exit status 2, not a traceback or an absurd figure later).

Each script builds its parser as :class:`Parser` and gives its numeric flags the type functions
below (:func:`count`, :func:`frame_size`, :func:`number`): a count of 0 or less, a size no network takes, a
rate that is not a finite positive number is refused by name. Not a benchmark itself (``make bench``
runs ``bench_*.py``)."""
from __future__ import annotations

import argparse
import math
import re
from typing import Callable, NoReturn

#: The largest frame a benchmark builds (px): params.yaml's ``world.resolution`` bound.
MAX_SIZE = 1024
#: A batch no benchmark needs more of (the paper's: 6); its memory grows with the size squared.
MAX_BATCH = 256
#: Timed steps, rounds, repeats, frames: far above any use, far below hours of work by mistake.
MAX_STEPS = 100_000
#: Threads, workers, runs side by side.
MAX_WORKERS = 256


class Parser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose errors are one line (``error: --size: ...``), exit 1."""

    def error(self, message: str) -> NoReturn:
        message = re.sub(r"^argument ([^:/\s]+)(?:/[^:\s]+)?: ", r"\1: ", message)
        self.exit(1, f"error: {' '.join(message.split())}\n")


def _got(text: str) -> str:
    return repr(text) if len(text) <= 40 else f"{text[:40]!r}... ({len(text)} characters)"


def _named(parse: Callable, name: str) -> Callable:
    parse.__name__ = name  # argparse names the type in its own messages
    return parse


def count(lo: int = 1, hi: int = MAX_STEPS) -> Callable[[str], int]:
    """A whole number from ``lo`` to ``hi``."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"expected a whole number from {lo} to {hi} (got {_got(text)})")
        return value
    return _named(parse, "count")


def frame_size(step: int = 32, lo: int | None = None, hi: int = MAX_SIZE) -> Callable[[str], int]:
    """A frame size in px: a multiple of ``step`` from ``lo`` (default ``step``) to ``hi`` (the
    compact network halves a frame three times, GradNorm SegNet's unpooling five)."""
    lo = step if lo is None else lo

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not lo <= value <= hi or value % step:
            raise argparse.ArgumentTypeError(f"expected a frame size in px, a multiple of {step} from {lo} to {hi} "
                                             f"(got {_got(text)})")
        return value
    return _named(parse, "frame_size")


def number(lo: float = 0.0, hi: float = math.inf, *, lo_inclusive: bool = False) -> Callable[[str], float]:
    """A finite number above ``lo`` (or at it, ``lo_inclusive``) and at most ``hi``."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        above = value >= lo if lo_inclusive else value > lo
        if not (math.isfinite(value) and above and value <= hi):
            bounds = f"{'at least' if lo_inclusive else 'above'} {lo:g}" + (f" and at most {hi:g}" if hi < math.inf
                                                                             else "")
            raise argparse.ArgumentTypeError(f"expected a finite number {bounds} (got {_got(text)})")
        return value
    return _named(parse, "number")
