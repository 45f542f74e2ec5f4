"""Error classes shared across modules (no imports, so no import cycles)."""
from __future__ import annotations


class RecordError(ValueError):
    """A raw record or dataset is unusable; the message names the frame id and the file."""


class RunError(RuntimeError):
    """A run cannot start or cannot save (bad input, a full disk); the message names the file or key."""
