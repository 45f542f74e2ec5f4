"""What a result follows from: a fingerprint of the source code that computes it.

The training stage may continue an interrupted run (its checkpoint is a persistent DVC
output), but only one of the same code, params and data: the checkpoint's digest includes
:func:`source_fingerprint`, so any change to the package or the stage modules starts the
run afresh instead of resuming or skipping with stale results.
"""
from __future__ import annotations

import functools
import hashlib
from pathlib import Path

#: the whole ``compact_perception`` package (this module sits in its ``learning/training`` subpackage)
PACKAGE_ROOT = Path(__file__).resolve().parents[2]


@functools.lru_cache(maxsize=1)
def source_fingerprint() -> str:
    """SHA-256 (16 hex) over every ``.py`` file of the package and of the sibling ``pipeline/``
    folder (when the package runs from a source checkout), by relative path and content."""
    h = hashlib.sha256()
    roots = [PACKAGE_ROOT, PACKAGE_ROOT.parent.parent / "pipeline"]
    for root in roots:
        if not root.is_dir():
            continue
        for path in sorted(root.rglob("*.py")):
            if "__pycache__" in path.parts:
                continue
            h.update(f"{root.name}/{path.relative_to(root).as_posix()}\0".encode())
            h.update(path.read_bytes())
            h.update(b"\0")
    return h.hexdigest()[:16]
