"""Error classes shared by the data readers (no imports, so no import cycles)."""
from __future__ import annotations


class RecordError(ValueError):
    """A raw record or dataset is unusable; the message names the frame id and the file."""
