"""A run's checkpoints: ``best.pt`` (the network at the best validation score) and ``last.pt``
(everything needed to resume bit-identically after the last finished epoch), written atomically
by rank 0, read back on a restart, and what a failed write leaves behind.

Every checkpoint is read onto the CPU, whatever device the run uses: ``load_state_dict`` moves each
tensor to where its module or optimiser lives, and the RNG states stay the CPU byte tensors
``torch.set_rng_state`` takes, so a run saved on one device resumes on another (a CPU run on a GPU
and the reverse: it continues, but its bytes are then those of neither device's uninterrupted run).
``last.pt`` also holds the CUDA generator of the run's GPU and the float16 GradScaler's state, so a
resumed GPU run continues the same sequence; a checkpoint of another resolved precision (``auto``
resolves per device) is refused in one line.

Every checkpoint is read with ``weights_only=True`` (tensors and plain containers): ``runs/`` is a
DVC output that can come from a shared cache or another checkout, and unpickling anything else
can run code. Checkpoints are written atomically, so one that does not read back is damaged, not
half-saved: that stops the run naming the file, and nothing is deleted.
"""
from __future__ import annotations

import errno
import logging
import shutil
from pathlib import Path
from typing import Any, Optional

import torch

from ...core import io
from ...core.errors import RunError, checkpoint_load_reason
from ...core.layout import RunPaths
from .distributed import Dist
from .state import RunState

log = logging.getLogger(__name__)

__all__ = ["save", "save_best", "save_last", "read_checkpoint", "load_resumable", "restore", "mark_finished",
           "clear_for_start", "discard_unsaved"]


def save(obj: Any, path: Path, final: Path) -> None:
    """``torch.save`` whose write failures are :class:`OSError` naming the file. On a full disk
    torch raises ``RuntimeError: [enforce fail at inline_container.cc] unexpected pos``.

    It writes through an open file: given a path, torch names the archive's root folder after
    the file, and ``path`` is a random temporary name (:func:`io.atomic_path`), so the same
    checkpoint would get other bytes on every run."""
    try:
        with open(path, "wb") as f:
            torch.save(obj, f)
    except OSError as err:
        raise OSError(err.errno, err.strerror, str(final)) from None
    except RuntimeError as err:
        if "inline_container" not in str(err) and "PytorchStreamWriter" not in str(err):
            raise
        free = shutil.disk_usage(Path(path).parent).free
        reason = "No space left on device" if free < (64 << 20) else f"write failed: {str(err).splitlines()[0]}"
        raise OSError(errno.ENOSPC if free < (64 << 20) else errno.EIO, reason, str(final)) from None


def _write(obj: Any, final: Path) -> None:
    with io.atomic_path(final) as tmp:
        save(obj, tmp, final)


def save_best(run: RunState, epoch: int) -> None:
    """``best.pt``: the network, its tasks, the epoch and its validation score."""
    _write({"model": run.model.state_dict(), "tasks": list(run.model.tasks), "epoch": epoch,
            "score": run.best_score}, run.spec.planned.paths.best)


def save_last(run: RunState, epoch: int) -> None:
    """``last.pt`` after ``epoch``: what :func:`restore` reads back, under the run's digest."""
    _write({
        "digest": run.spec.digest, "epoch": epoch, "model": run.model.state_dict(),
        "optimizer": run.optimizer.state_dict(), "weighting": run.weighting.state_dict(),
        "plateau": run.plateau.state_dict(), "stopper": run.stopper.state_dict(), "history": run.history,
        "best_score": run.best_score, "best_epoch": run.best_epoch, "lr": run.lr,
        "torch_rng": torch.get_rng_state(), "stopped_early": run.stopped_early,
        "elapsed_s": run.elapsed(), "finished": False, "untrained_score": run.untrained_score,
        "device": run.spec.device.type, "precision": run.precision, "scaler": run.scaler.state_dict(),
        "cuda_rng": torch.cuda.get_rng_state(run.spec.device) if run.spec.device.type == "cuda" else None,
    }, run.spec.planned.paths.last)


def _reason(err: Exception) -> str:
    """One short line of why ``torch.load`` refused a file (:func:`..core.errors.checkpoint_load_reason`:
    what every checkpoint reader says, never torch's advice to load it unsafely)."""
    return checkpoint_load_reason(err)


def read_checkpoint(path: Path, remedy: str = "delete it to retrain from scratch") -> dict:
    """The checkpoint at ``path``, read onto the CPU with ``weights_only=True``; :class:`RunError`
    naming the file (and ``remedy``) when it does not read back as a mapping."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises RuntimeError, EOFError, UnpicklingError, ... on damage
        raise RunError(f"{path}: unreadable checkpoint ({_reason(err)}); {remedy}") from None
    if not isinstance(state, dict):
        raise RunError(f"{path}: unreadable checkpoint (a {type(state).__name__}, not a checkpoint); {remedy}")
    return state


def load_resumable(path: Path, digest: str) -> Optional[dict]:
    """The checkpoint at ``path`` when it belongs to this run (the same ``digest``: code, params,
    data); ``None`` (start afresh) when there is none or it is of another run. An unreadable one is
    an error (:func:`read_checkpoint`): it was written atomically, so it is damaged, and starting
    afresh would delete a finished run's results."""
    if not path.exists():
        return None
    state = read_checkpoint(path)
    if state.get("digest") != digest:
        log.info("%s: the checkpoint is of other code, params or data; starting afresh", path.parent)
        return None
    return state


def restore(run: RunState, state: dict) -> None:
    """Put a ``last.pt`` state (:func:`save_last`, read on the CPU) back into ``run``: it continues
    after that epoch, on the run's device."""
    _check_precision(run, state)
    run.model.load_state_dict(state["model"])
    run.optimizer.load_state_dict(state["optimizer"])
    run.weighting.load_state_dict(state["weighting"])
    run.plateau.load_state_dict(state["plateau"])
    run.stopper.load_state_dict(state["stopper"])
    run.next_epoch, run.history = state["epoch"] + 1, state["history"]
    run.best_score, run.best_epoch, run.lr = state["best_score"], state["best_epoch"], state["lr"]
    run.untrained_score = state.get("untrained_score")
    torch.set_rng_state(state["torch_rng"])
    if state.get("scaler"):
        run.scaler.load_state_dict(state["scaler"])
    _restore_cuda_rng(run, state)
    run.elapsed_before, run.stopped_early = state["elapsed_s"], bool(state.get("stopped_early"))


def _check_precision(run: RunState, state: dict) -> None:
    """A checkpoint trained in another precision (``train.precision: auto`` resolves per device:
    bf16 on a recent GPU, fp32 on most CPUs) is refused: one run in two precisions is neither."""
    saved = state.get("precision", "fp32")
    if saved != run.precision:
        raise RunError(f"{run.spec.planned.paths.last}: trained in {saved} on {state.get('device', 'cpu')}, this "
                       f"process resolves train.precision to {run.precision} on {run.spec.device.type}; set "
                       f"train.precision to {saved} to continue it, or delete the file to retrain from scratch")


def _restore_cuda_rng(run: RunState, state: dict) -> None:
    """The CUDA generator of the run's GPU as saved; a run saved on another device type keeps the
    generator its seed gave it, and says so."""
    saved_on, here = state.get("device", "cpu"), run.spec.device.type
    if here == "cuda" and state.get("cuda_rng") is not None:
        torch.cuda.set_rng_state(state["cuda_rng"], run.spec.device)
    if saved_on != here:
        log.warning("%s: saved on %s, resuming on %s: the run continues, with neither device's bytes",
                    run.spec.planned.paths.run_dir, saved_on, here)


def mark_finished(path: Path) -> None:
    """Flag ``last.pt`` as a complete run (a restart then returns its summary)."""
    state = read_checkpoint(path)
    state["finished"] = True
    _write(state, path)


def clear_for_start(paths: RunPaths, resuming: bool) -> None:
    """Rank 0, before the epochs: a fresh start removes the files of any earlier run; the dvclive
    folder and the temporary files of a write killed before its rename (:func:`io.remove_leftovers`)
    are always removed (the logs are rebuilt from the checkpoint's history)."""
    io.remove_leftovers(paths.run_dir)
    if not resuming:
        for stale in (paths.last, paths.best, paths.summary):
            stale.unlink(missing_ok=True)
    shutil.rmtree(paths.live, ignore_errors=True)


def discard_unsaved(paths: RunPaths, dist: Dist) -> None:
    """After a failed write: a run that never saved an epoch leaves nothing behind (rank 0)."""
    if dist.is_main and not paths.last.exists():
        shutil.rmtree(paths.live, ignore_errors=True)
        for stale in (paths.best, paths.summary):
            stale.unlink(missing_ok=True)
