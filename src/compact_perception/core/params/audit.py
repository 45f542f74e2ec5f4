"""Which params keys a stage reads: the check behind "every params key it reads is a dependency".

With ``COMPACT_PERCEPTION_PARAMS_AUDIT=<file>`` in the environment, each stage's validated
params are wrapped in :class:`ParamsView`, which records the dotted path of every key the
stage reads, and the stage appends ``{"stage": ..., "argv": ..., "keys": [...]}`` as one JSON
line to ``<file>`` when it exits. The end-to-end test runs ``dvc repro`` with it and compares
each stage's keys with the ``params:`` that ``dvc.yaml`` lists for it. Without the variable
nothing is wrapped; the audit never changes a result.

One line per process: a stage's worker processes (``training.parallel``) receive its params
pickled, and a view unpickles as a view recording into its own process's log, written when that
process exits.

A value read from a model that says where its values are written (``key_of(name)``: a merged
recipe of ``train.models.<id>`` inherits keys of ``train.recipe``) records that key too, and a
method of a params model runs on the view, so what it reads is recorded.
"""
from __future__ import annotations

import atexit
import inspect
import json
import os
import sys
import types
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pydantic import BaseModel

ENV_VAR = "COMPACT_PERCEPTION_PARAMS_AUDIT"


class _Log:
    def __init__(self) -> None:
        self.keys: set[str] = set()

    def add(self, path: str) -> None:
        self.keys.add(path)


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _read(log: _Log, model: BaseModel, path: str, name: str) -> None:
    """Record that ``name`` of ``model`` (at ``path``) was read, and where its value is written."""
    log.add(_join(path, name))
    key_of = getattr(model, "key_of", None)
    if callable(key_of):
        log.add(key_of(name))


def _wrap(value: Any, path: str, log: _Log) -> Any:
    if isinstance(value, BaseModel):
        return ParamsView(value, path, log)
    if isinstance(value, Mapping):
        return _MappingView(value, path, log)
    return value


class ParamsView:
    """Read-only view of a params model that records each key read (``a.b.c``).

    Reading a field records its path; ``model_dump`` records every field (and extra key) it
    dumps; a value read from ``Params``' values at its scale (``_at_scale``) records its key and
    ``scale``; a public method or property of the model's own class (``Scaled.at``,
    ``Params.study_recipe``, ``Params.resolution``) runs with this view as ``self``; anything else
    is passed through.
    """

    def __init__(self, model: BaseModel, path: str, log: _Log) -> None:
        object.__setattr__(self, "_model", model)
        object.__setattr__(self, "_path", path)
        object.__setattr__(self, "_log", log)

    def __getattr__(self, name: str) -> Any:
        model, path, log = self._model, self._path, self._log
        value = getattr(model, name)
        if name in type(model).model_fields:
            _read(log, model, path, name)
            return _wrap(value, _join(path, name), log)
        if name == "_at_scale":  # the values at the file's scale, resolved once (Params.model_post_init):
            log.add(_join(path, "scale"))  # a value read there is its key's, at the scale ``scale`` chose
            return _MappingView(value, path, log)
        if name == "model_dump":
            def dump(*args: Any, exclude: Any = None, **kwargs: Any) -> Any:
                for key in (*type(model).model_fields, *(model.model_extra or {})):
                    if not exclude or key not in exclude:
                        _read(log, model, path, key)
                return model.model_dump(*args, exclude=exclude, **kwargs)
            return dump
        method = inspect.getattr_static(type(model), name, None)
        if isinstance(method, property):  # computed from fields (``Params.resolution``): read through the view
            return method.fget(self)
        if inspect.isfunction(method) and not name.startswith("_") and name not in vars(BaseModel):
            return types.MethodType(method, self)
        return value

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("params are read-only")

    def __reduce__(self) -> tuple:
        """Pickled (to a stage's worker process) as the model and its path: unpickled, a view
        recording into that process's log (:func:`_reopened`)."""
        return _reopened, (self._model, self._path)


class _MappingView(Mapping):
    """A dict-valued param (``train.models``) whose item reads are recorded per key."""

    def __init__(self, data: Mapping, path: str, log: _Log) -> None:
        self._data, self._path, self._log = data, path, log

    def __getitem__(self, key: str) -> Any:
        self._log.add(_join(self._path, str(key)))
        return _wrap(self._data[key], _join(self._path, str(key)), self._log)

    def __contains__(self, key: object) -> bool:
        self._log.add(_join(self._path, str(key)))
        return key in self._data

    def __iter__(self):
        self._log.add(self._path)  # listing the keys reads the whole mapping
        return iter(self._data)

    def __len__(self) -> int:
        self._log.add(self._path)
        return len(self._data)

    def __reduce__(self) -> tuple:
        return _reopened, (self._data, self._path)


#: This process's record of the keys read (:func:`_process_log`), written once at its exit.
_PROCESS_LOG: _Log | None = None


def _process_log(target: str) -> _Log:
    """The log of this process, created (and its line registered to be appended to ``target`` at
    exit) on first use."""
    global _PROCESS_LOG
    if _PROCESS_LOG is None:
        log = _PROCESS_LOG = _Log()

        def _write() -> None:
            line = {"stage": Path(sys.argv[0]).stem, "argv": sys.argv[1:], "keys": sorted(leaf_keys(log.keys))}
            with open(target, "a") as fh:
                fh.write(json.dumps(line) + "\n")

        atexit.register(_write)
    return _PROCESS_LOG


def audited(params: BaseModel) -> Any:
    """``params`` itself, or a recording :class:`ParamsView` when the audit is on."""
    return _reopened(params, "")


def _reopened(value: Any, path: str) -> Any:
    """``value`` (params, a section of them at ``path``) recording into this process's log when the
    audit is on (a spawned worker inherits the stage's environment, so its line is written too)."""
    target = os.environ.get(ENV_VAR)
    return _wrap(value, path, _process_log(target)) if target else value


def leaf_keys(keys: set[str]) -> set[str]:
    """The most specific keys read (``a.b`` is dropped when ``a.b.c`` was read)."""
    return {k for k in keys if not any(o.startswith(k + ".") for o in keys)}
