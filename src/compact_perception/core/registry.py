"""A tiny name -> factory registry, keyed by the ids used in params.yaml."""
from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType
from typing import Callable, Generic, Iterable, Iterator, TypeVar

T = TypeVar("T")


def import_submodules(package: str, path: Iterable[str]) -> dict[str, ModuleType]:
    """Import every module of ``package`` (its ``__path__``), in name order, and return them by
    their last name, so a module the package finds (a model network) or one that registers an
    entry on import (a weighting method's ``@register(...)``) needs no line in the package's
    ``__init__``: it is one new file. The code fingerprint counts every module of such a package
    (``learning/training/provenance.py``)."""
    return {name: importlib.import_module(f"{package}.{name}")
            for name in sorted(m.name for m in pkgutil.iter_modules(path))}


class Registry(Generic[T]):
    """Maps ids (as written in params.yaml) to factories; unknown ids are clear errors."""

    def __init__(self, kind: str, *, ordered: bool = False) -> None:
        """``ordered``: iterate in registration order (a table's row order), else sorted by id."""
        self.kind = kind
        self.ordered = ordered
        self._items: dict[str, T] = {}

    def register(self, key: str) -> Callable[[T], T]:
        def deco(obj: T) -> T:
            if key in self._items:
                raise KeyError(f"{self.kind} {key!r} registered twice")
            self._items[key] = obj
            return obj

        return deco

    def __getitem__(self, key: str) -> T:
        try:
            return self._items[key]
        except KeyError:
            known = ", ".join(self.keys())
            raise KeyError(f"unknown {self.kind} {key!r}; known: {known}") from None

    def __contains__(self, key: object) -> bool:
        return key in self._items

    def __iter__(self) -> Iterator[str]:
        return iter(self.keys())

    def __len__(self) -> int:
        return len(self._items)

    def keys(self) -> list[str]:
        return list(self._items) if self.ordered else sorted(self._items)
