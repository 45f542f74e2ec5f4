"""Error classes shared across modules (no imports of this package, so no import cycles)."""
from __future__ import annotations

import errno
import pickle
import re


class RecordError(ValueError):
    """A raw record or dataset is unusable; the message names the frame id and the file."""


class ReportInputError(ValueError):
    """A report input is malformed (a run's metrics, the record of runs trained to their plateau,
    or a file that record is made from); the message names the file and key."""


class RunError(RuntimeError):
    """A run cannot start or cannot save (bad input, a full disk); the message names the file or key."""


class NonFinite(ArithmeticError):
    """A loss, score or loss weight that is not a finite number: the run has diverged (e.g. a too
    large lr). The training loop turns it into a :class:`RunError` naming the run and the epoch."""


#: The OS's reasons a file could not be read or written (a full disk, a quota, a read-only or
#: vanished folder, no permission): when the OS names no file, the folder a stage writes is blamed.
STORAGE_ERRNOS: frozenset[int] = frozenset(
    getattr(errno, name) for name in ("ENOSPC", "EDQUOT", "EROFS", "EACCES", "EPERM", "EFBIG", "EIO", "ENOENT",
                                      "ENOTDIR", "EISDIR", "EEXIST", "ENAMETOOLONG", "ESTALE") if hasattr(errno, name))


def failed_call(err: BaseException) -> str:
    """The call an exception came from (its innermost frame, ``module.function``), to name the
    operation when the OS names no file."""
    tb = err.__traceback__
    if tb is None:
        return type(err).__name__
    while tb.tb_next is not None:
        tb = tb.tb_next
    code = tb.tb_frame.f_code
    return f"{tb.tb_frame.f_globals.get('__name__', '?')}.{getattr(code, 'co_qualname', code.co_name)}"


def os_error_line(err: OSError, where: object, doing: str = "write") -> str:
    """One line for a failed read or write (a full disk, a read-only folder): the file the OS
    names, else ``where``, and the OS's reason (``No space left on device``). An OSError raised
    with a message of its own (``FileNotFoundError("<file>: no best checkpoint")``) is that message.
    An error that is not a file's (a broken pipe to a worker process, no memory to fork) and names
    no file is not blamed on ``where``: the line names the call that failed."""
    if err.errno is None and not err.filename:
        return " ".join(str(err).split())
    reason = err.strerror or str(err)
    if err.filename or err.errno in STORAGE_ERRNOS:
        return f"{err.filename or where}: could not {doing} ({reason})"
    return f"{failed_call(err)} failed ({reason}; not a file of {where})"


#: Words of torch's advice on a refused checkpoint that would have the user load it unsafely
#: (``weights_only=False``, allowlisting the global it names): never repeated in a message.
_UNSAFE_ADVICE = ("weights_only", "safe_globals", "trusted source", "arbitrary code")


def checkpoint_load_reason(err: Exception) -> str:
    """One short line of why ``torch.load(..., weights_only=True)`` refused a file, in the training
    side's words for every checkpoint reader: a pickle holding more than tensors is named as such
    (with the global it names), never with torch's advice to re-run the load unsafely."""
    lines = [line.strip() for line in str(err).splitlines() if line.strip()]
    text = " ".join(lines)
    if isinstance(err, pickle.UnpicklingError) or "Weights only load failed" in text:
        found = re.search(r"GLOBAL ([\w.]+)", text)
        what = f": unsupported GLOBAL {found.group(1)}" if found else ""
        return f"it holds more than tensors and plain data, not loaded{what}"
    reason = lines[0].split(". ")[0][:200] if lines else type(err).__name__
    return type(err).__name__ if any(w in reason for w in _UNSAFE_ADVICE) else reason
