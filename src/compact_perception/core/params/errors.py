"""A params file's errors (:class:`ParamsError`): one line naming every offending key, each at
the params key that holds its value (a merged recipe's inherited keys sit in ``train.recipe``)."""
from __future__ import annotations

import reprlib
from collections.abc import Mapping
from typing import Any, Callable

from pydantic import ValidationError

__all__ = ["ParamsError", "format_error", "shown", "cut", "MAX_PROBLEM_CHARS", "MAX_PROBLEMS"]

#: The longest one problem of a message may be, and the most problems a message names: a value
#: of 10^5 items once made a one-line error of 722,360 characters.
MAX_PROBLEM_CHARS = 300
MAX_PROBLEMS = 10

#: How a value is shown in a message: a few items of each container, the start of a long string
#: (``reprlib`` walks only what it shows, whatever the value's size).
_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxtuple, _REPR.maxlist, _REPR.maxdict, _REPR.maxset = 2, 4, 4, 4, 4
_REPR.maxstring, _REPR.maxother, _REPR.maxlong = 60, 60, 40


class ParamsError(ValueError):
    """params.yaml is invalid; the message names every offending key."""


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def cut(text: str, limit: int = MAX_PROBLEM_CHARS) -> str:
    """``text`` on one line, cut to ``limit`` characters with its full size said where it is longer."""
    text = _one_line(text)
    return text if len(text) <= limit else f"{text[:limit]}... (cut; {len(text)} characters)"


def shown(value: Any) -> str:
    """``repr(value)`` bounded: a long string, number or container shown in part, with its size."""
    if isinstance(value, int) and value.bit_length() > 128:  # repr refuses past 4300 digits
        return f"an integer of {value.bit_length()} bits"
    text = _REPR.repr(value)
    if isinstance(value, (str, bytes)) and len(value) > _REPR.maxstring:
        return f"{text} ({len(value)} characters)"
    if isinstance(value, (list, tuple, dict, set)) and "..." in text:
        n = len(value)
        return f"{text} ({type(value).__name__} of {n} item{'' if n == 1 else 's'})"
    return text


def _format(err: ValidationError, source: str, place: Callable[[tuple], tuple] = lambda loc: loc) -> str:
    """One line: ``<file>: <key>: <problem> (got <value>)``, problems joined by ``; ``. ``place``
    maps an error's location to the params key that holds the value (a merged recipe's inherited
    keys sit in ``train.recipe``); a problem found at several places is named once. A value is
    shown bounded (:func:`shown`), each problem cut at :data:`MAX_PROBLEM_CHARS` and at most
    :data:`MAX_PROBLEMS` named, so the line stays short whatever the file holds."""
    problems: dict[str, None] = {}  # ordered, each once
    for e in err.errors():
        key = ".".join(str(p) for p in place(tuple(e["loc"]))) or "<root>"
        msg = e["msg"]
        if e["type"] == "extra_forbidden":
            msg = "unknown key (not in the schema)"
        got = e.get("input")
        got_s = "" if e["type"] in ("extra_forbidden", "missing") or isinstance(got, dict) else f" (got {shown(got)})"
        if e["type"] == "float_type" and isinstance(got, str) and _is_number(got):
            got_s += " (YAML reads an exponent without a dot as text: write e.g. 1.0e-4)"
        problems[_one_line(f"{cut(key, 120)}: {cut(msg)}{got_s}")] = None
    head = f"{source}: " if len(problems) == 1 else f"{source}: {len(problems)} invalid parameters: "
    more = len(problems) - MAX_PROBLEMS
    return head + "; ".join(list(problems)[:MAX_PROBLEMS]) + (f"; and {more} more" if more > 0 else "")


def format_error(err: ValidationError, source: str, key: str = "") -> str:
    """:func:`_format` for a section validated on its own (a weighting's settings) at params key ``key``."""
    return _format(err, source, lambda loc: _in_params(loc, key, {}))


def _in_params(loc: tuple, key: str, inherited: Mapping[str, str]) -> tuple:
    """Location ``loc`` inside the recipe read at params key ``key`` (``""``: not read from params),
    as the params key that holds the value there."""
    if loc and loc[0] in inherited:
        return (*inherited[loc[0]].split("."), *loc[1:])
    return (*(key.split(".") if key else ()), *loc)
