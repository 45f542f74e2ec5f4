"""A params file's errors (:class:`ParamsError`): one line naming every offending key, each at
the params key that holds its value (a merged recipe's inherited keys sit in ``train.recipe``)."""
from __future__ import annotations

from collections.abc import Mapping
from typing import Callable

from pydantic import ValidationError

__all__ = ["ParamsError", "format_error"]


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


def _format(err: ValidationError, source: str, place: Callable[[tuple], tuple] = lambda loc: loc) -> str:
    """One line: ``<file>: <key>: <problem> (got <value>)``, problems joined by ``; ``. ``place``
    maps an error's location to the params key that holds the value (a merged recipe's inherited
    keys sit in ``train.recipe``); a problem found at several places is named once."""
    problems: list[str] = []
    for e in err.errors():
        key = ".".join(str(p) for p in place(tuple(e["loc"]))) or "<root>"
        msg = e["msg"]
        if e["type"] == "extra_forbidden":
            msg = "unknown key (not in the schema)"
        got = e.get("input")
        got_s = "" if e["type"] in ("extra_forbidden", "missing") or isinstance(got, dict) else f" (got {got!r})"
        if e["type"] == "float_type" and isinstance(got, str) and _is_number(got):
            got_s += " (YAML reads an exponent without a dot as text: write e.g. 1.0e-4)"
        problem = _one_line(f"{key}: {msg}{got_s}")
        if problem not in problems:
            problems.append(problem)
    head = f"{source}: " if len(problems) == 1 else f"{source}: {len(problems)} invalid parameters: "
    return head + "; ".join(problems)


def format_error(err: ValidationError, source: str, key: str = "") -> str:
    """:func:`_format` for a section validated on its own (a weighting's settings) at params key ``key``."""
    return _format(err, source, lambda loc: _in_params(loc, key, {}))


def _in_params(loc: tuple, key: str, inherited: Mapping[str, str]) -> tuple:
    """Location ``loc`` inside the recipe read at params key ``key`` (``""``: not read from params),
    as the params key that holds the value there."""
    if loc and loc[0] in inherited:
        return (*inherited[loc[0]].split("."), *loc[1:])
    return (*(key.split(".") if key else ()), *loc)
