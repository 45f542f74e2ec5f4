"""The building blocks of the params schema (:mod:`compact_perception.core.params`): the strict
base model every section derives from, the per-scale value (:class:`Scaled`) and its checks, and
the upper bounds of the counts that size memory, processes or disk."""
from __future__ import annotations

from typing import Any, Generic, Literal, Optional, TypeVar

from pydantic import BaseModel, ConfigDict
from pydantic_core import PydanticCustomError

__all__ = ["Strict", "Scaled", "ScaleName", "SCALES", "resolve_scale", "MAX_FRAMES", "MAX_SCENES", "MAX_WORKERS",
           "MAX_BATCH",
           "MAX_SAVED_PREDICTIONS"]

T = TypeVar("T")

ScaleName = Literal["default", "full", "paper"]
#: The values of ``scale``, each a field of every :class:`Scaled`.
SCALES: tuple[str, ...] = ("default", "full", "paper")


class Strict(BaseModel):
    """Base for every section: unknown keys are rejected, types are strict (no bool/str -> int),
    and a float must be finite (YAML's ``.inf``/``.nan`` are errors: an infinite lr diverges)."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)


class Scaled(Strict, Generic[T]):
    """A value that differs between the scales (``default``, ``full``, ``paper``)."""

    default: T
    full: T
    paper: T

    def at(self, scale: ScaleName) -> T:
        return getattr(self, scale)

    def __reduce__(self) -> tuple:
        """Pickled by its type argument: a parametrised class (``Scaled[int]``) has no name pickle
        can import, and a stage hands its params whole to spawned worker processes
        (``training.parallel``). Unpickled, it is the same class with the same state, not re-validated."""
        return _parametrised, (self.__pydantic_generic_metadata__["args"],), self.__getstate__()


def resolve_scale(value: Any, scale: str) -> Any:
    """The one resolver of ``scale``: ``value`` (plain params data, as in params.yaml or a model's
    dump) with every per-scale mapping (exactly the keys of :data:`SCALES`) replaced by its value
    at ``scale``. ``Params`` applies it once when it loads (its accessors read the result); a
    record's dumped settings are read through it at ``full`` (``core.plateau_record``)."""
    if isinstance(value, dict):
        if value and set(value) == set(SCALES):
            return resolve_scale(value[scale], scale)
        return {k: resolve_scale(v, scale) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [resolve_scale(v, scale) for v in value]
    return value


def _parametrised(args: tuple) -> Scaled:
    """An empty :class:`Scaled` of type argument ``args``, whose state pickle then sets."""
    cls = Scaled[args[0] if len(args) == 1 else args]
    return cls.__new__(cls)


def _scaled_at_least(v: Optional[Scaled[int]], lo: int) -> Optional[Scaled[int]]:
    """Every scale of an integer :class:`Scaled` count is ``>= lo``."""
    if v is not None:
        for name in SCALES:
            if getattr(v, name) < lo:
                raise ValueError(f"{name} must be at least {lo}, got {getattr(v, name)}")
    return v


def _scaled_at_most(v: Optional[Scaled[int]], hi: int, why: str) -> Optional[Scaled[int]]:
    """Every scale of an integer :class:`Scaled` count that sizes memory, processes or disk is
    ``<= hi``: ``default: 1000000000 exceeds 1000000 (<why>)``, before any work starts."""
    if v is not None:
        for name in SCALES:
            if getattr(v, name) > hi:
                raise PydanticCustomError("too_large", "{scale}: {value} exceeds {hi} ({why})",
                                          {"scale": name, "value": getattr(v, name), "hi": hi, "why": why})
    return v


#: Upper bounds of the counts that size memory, processes or disk (issue 26): far above every
#: scale's value (the paper's 10000 frames, 850 scenes, batch 6), far below what exhausts a machine.
MAX_FRAMES = 1_000_000
MAX_SCENES = 10_000
MAX_WORKERS = 256
MAX_BATCH = 1024
MAX_SAVED_PREDICTIONS = 10_000


def _scaled_distinct_seeds(v: Scaled[list[int]]) -> Scaled[list[int]]:
    """Training seeds at every scale: a non-empty list of distinct non-negative integers."""
    for name in SCALES:
        seeds = getattr(v, name)
        if not seeds or any(k < 0 for k in seeds) or len(set(seeds)) != len(seeds):
            raise ValueError(f"{name}: expected a non-empty list of distinct non-negative integers, got {seeds}")
    return v
