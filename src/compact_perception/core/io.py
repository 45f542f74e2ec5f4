"""Atomic, deterministic writing of outputs (SPEC 9: nothing half-written), and reading a JSON
input whose every error names the file (:func:`read_json`)."""
from __future__ import annotations

import contextlib
import errno
import hashlib
import io as _io
import json
import os
import shutil
import tempfile
import zipfile
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from .errors import ReportInputError

_ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary sibling path; on success rename it onto ``path``.

    On any exception the temporary file is removed and ``path`` is untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o644)  # mkstemp creates 0600; outputs are ordinary shared files
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def check_writable(*folders: str | os.PathLike) -> None:
    """Raise the OSError (naming the folder) a write into any of ``folders`` would meet (read-only,
    no permission, a read-only file system), before a stage writes anything: a file is created and
    removed in each folder, or in its nearest existing parent where the folder is not there yet
    (nothing is created in its place)."""
    for folder in folders:
        target = Path(folder)
        probe = target
        while not probe.exists() and probe != probe.parent:
            probe = probe.parent
        if not probe.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, "not a folder", str(probe))
        try:
            fd, tmp = tempfile.mkstemp(prefix=".write-check.", suffix=".tmp", dir=probe)
        except OSError as err:
            raise type(err)(err.errno, err.strerror or str(err), str(target)) from None
        os.close(fd)
        os.unlink(tmp)


def remove_leftovers(folder: str | os.PathLike) -> list[Path]:
    """Delete the temporary files :func:`atomic_path` leaves in ``folder`` when its process is
    killed between creating one and renaming it (``.<name>.<random>.tmp``); returns them. Call it
    where a process takes the folder over (a training run resuming), never while another writes."""
    folder = Path(folder)
    found = sorted(folder.glob(".*.tmp")) if folder.is_dir() else []
    for f in found:
        f.unlink(missing_ok=True)
    return found


def read_json(path: str | os.PathLike) -> dict[str, Any]:
    """Parse a JSON object; errors (a missing file too) name the file (:class:`ReportInputError`)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ReportInputError(f"{path}: missing") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ReportInputError(f"{path}: not valid JSON ({err})") from None
    except RecursionError:  # arrays or objects nested deeper than the parser's recursion limit
        raise ReportInputError(f"{path}: not valid JSON (nested too deeply to read)") from None
    if not isinstance(data, dict):
        raise ReportInputError(f"{path}: expected a JSON object")
    return data


def sha256_file(path: str | os.PathLike) -> str:
    """SHA-256 (hex) of a file's bytes, read in 4 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 22), b""):
            h.update(chunk)
    return h.hexdigest()


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | os.PathLike, text: str) -> None:
    write_bytes(path, text.encode("utf-8"))


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write ``obj`` as sorted, indented JSON, atomically."""
    write_text(path, json.dumps(obj, indent=2, sort_keys=True) + "\n")


def npz_bytes(arrays: dict[str, np.ndarray], compress: bool = True) -> bytes:
    """Serialise arrays as an .npz archive with fixed timestamps (byte-identical reruns).

    ``numpy.savez`` stamps entries with the current time; this does not.
    """
    buf = _io.BytesIO()
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(buf, "w", compression=method) as zf:
        for name in sorted(arrays):
            arr = np.ascontiguousarray(arrays[name])
            member = _io.BytesIO()
            np.lib.format.write_array(member, arr, allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_EPOCH)
            info.compress_type = method
            info.external_attr = 0o644 << 16
            zf.writestr(info, member.getvalue())
    return buf.getvalue()


def write_npz(path: str | os.PathLike, arrays: dict[str, np.ndarray], compress: bool = True) -> None:
    """Atomically write a deterministic .npz (see :func:`npz_bytes`)."""
    write_bytes(path, npz_bytes(arrays, compress))


def write_figure(fig: Any, path: str | os.PathLike, dpi: int = 100, tight: bool = False) -> Path:
    """Render a matplotlib figure to PNG and write it atomically; the figure is closed."""
    import matplotlib.pyplot as plt

    buf = _io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight" if tight else None)
    finally:
        plt.close(fig)
    write_bytes(path, buf.getvalue())
    return Path(path)


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Build a directory under a temporary sibling name; swap it into place on success.

    An interrupted run leaves only ``.<name>.partial`` (removed on the next attempt),
    never a directory at ``path`` that a later stage could take for complete.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".{path.name}.partial"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if path.exists():
        shutil.rmtree(path)
    os.replace(tmp, path)
