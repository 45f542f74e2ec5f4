"""Error classes shared across modules (no imports, so no import cycles)."""
from __future__ import annotations


class RecordError(ValueError):
    """A raw record or dataset is unusable; the message names the frame id and the file."""


class RunError(RuntimeError):
    """A run cannot start or cannot save (bad input, a full disk); the message names the file or key."""


def os_error_line(err: OSError, where: object) -> str:
    """One line for a failed read or write (a full disk, a read-only folder): the file the OS
    names, else ``where``, and the OS's reason (``No space left on device``)."""
    return f"{err.filename or where}: could not write ({err.strerror or err})"
