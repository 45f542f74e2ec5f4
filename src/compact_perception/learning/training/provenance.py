"""What a result follows from: a fingerprint of the source code that computes it.

The training stage may continue an interrupted run (its checkpoint is a persistent DVC
output), but only one of the same code, params and data: the checkpoint's digest includes
:func:`source_fingerprint`, so a change to the code that can change a run's bytes starts the run
afresh instead of resuming or skipping with stale results.

Which code that is: every module a training run can execute, found by following the imports
(lazy ones too) from the run's own module (:data:`ENTRY_MODULES`: ``learning/training/train``)
and from the stage package's start-up (``pipeline/__init__``, which pins the numeric libraries).
How the runs are executed (``execution/``: the pool, submitit), how a stage plans and reports
them (``pipeline/train.py``, the report, the evaluation) is not: a change there restarts no run.
:func:`fingerprinted_files` lists the files (``tests/test_reproducibility.py`` names them).
"""
from __future__ import annotations

import ast
import functools
import hashlib
from pathlib import Path
from typing import Optional

#: the whole ``compact_perception`` package (this module sits in its ``learning/training`` subpackage)
PACKAGE_ROOT = Path(__file__).resolve().parents[2]
#: The modules a run starts from: the training run, and the stage package that pins the numeric
#: libraries in every process that trains (read when the package runs from a source checkout).
ENTRY_MODULES = ("compact_perception.learning.training.train", "pipeline")
_PROJECT = ("compact_perception", "pipeline")


def _roots() -> dict[str, Path]:
    return {"compact_perception": PACKAGE_ROOT, "pipeline": PACKAGE_ROOT.parent.parent / "pipeline"}


def _module_file(name: str, roots: dict[str, Path]) -> Optional[Path]:
    """The source file of a project module (``pkg/__init__.py`` for a package), or ``None``."""
    parts = name.split(".")
    if parts[0] not in roots:
        return None
    base = roots[parts[0]].joinpath(*parts[1:])
    for cand in ((base.with_suffix(".py"),) if len(parts) > 1 else ()) + (base / "__init__.py",):
        if cand.is_file():
            return cand
    return None


def _imports(name: str, path: Path) -> set[str]:
    """Every project module importing ``name`` (at ``path``) runs, lazy imports included, each with
    the packages above it; a package that calls ``import_submodules`` (``core.registry``: the
    model networks, the weighting methods) imports every module in its folder."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_bytes(), str(path))):
        if (path.name == "__init__.py" and isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                and node.func.id == "import_submodules"):
            found.update(f"{name}.{p.stem}" for p in path.parent.glob("*.py") if p.name != "__init__.py")
        elif isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - (node.level - 1)] + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names)
    out: set[str] = set()
    for mod in found:
        parts = mod.split(".")
        if parts[0] in _PROJECT:
            out.update(".".join(parts[:k]) for k in range(1, len(parts) + 1))
    return out


def _closure() -> list[tuple[str, Path]]:
    """``(root name, file)`` of every module the entry modules can import, sorted."""
    roots = _roots()
    seen: dict[Path, str] = {}
    todo = [m for m in ENTRY_MODULES]
    while todo:
        name = todo.pop()
        path = _module_file(name, roots)
        if path is None or path in seen:
            continue
        seen[path] = name.split(".")[0]
        todo.extend(_imports(name, path))
        todo.extend(".".join(name.split(".")[:k]) for k in range(1, name.count(".") + 1))  # its packages
    return sorted(((root, path) for path, root in seen.items()),
                  key=lambda rp: f"{rp[0]}/{rp[1].relative_to(roots[rp[0]]).as_posix()}")


def fingerprinted_files() -> list[str]:
    """The files :func:`source_fingerprint` hashes, as ``compact_perception/...`` and ``pipeline/...``."""
    roots = _roots()
    return [f"{root}/{path.relative_to(roots[root]).as_posix()}" for root, path in _closure()]


@functools.lru_cache(maxsize=1)
def source_fingerprint() -> str:
    """SHA-256 (16 hex) over every ``.py`` file a training run can execute (:func:`fingerprinted_files`),
    by relative path and content."""
    h = hashlib.sha256()
    roots = _roots()
    for root, path in _closure():
        h.update(f"{root}/{path.relative_to(roots[root]).as_posix()}\0".encode())
        h.update(path.read_bytes())
        h.update(b"\0")
    return h.hexdigest()[:16]
