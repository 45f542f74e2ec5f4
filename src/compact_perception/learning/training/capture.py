"""The training step through fixed buffers, replayed as a CUDA graph (``train.cuda_graphs``).

A GPU step of the compact networks is bound by kernel launches, not arithmetic: thousands of small
kernels, each queued by Python. A CUDA graph records one step's kernels once and replays them with
one launch. A graph replays fixed memory, so the captured step reads its batch from buffers the
host copies each batch into, adds to the epoch's sums in place (:class:`~.epoch.EpochSums`) and
marks its step index in a device tensor; everything else is the eager step's own code
(:func:`~.epoch.step_on_device`).

What is captured: the *ordinary* steps of an epoch, neither its first (MGN records L_i(0) there)
nor its last (the epoch's divergence check reads the device there, MGN updates its weights); those
two run eagerly, on the same parameters and sums. A graph holds what was true when it was
captured (the learning rate, the loss weights' tensor, the epoch's sums), so a new one is captured
whenever one of them changes: once per epoch, at its second step.

Where it is captured (``auto``; ``off`` never): a CUDA device, one process, no ``torch.compile``,
fp32 or bf16 (a float16 GradScaler reads its scale every step), a network whose losses need no
per-batch pixel lists (PolarNet's and SegNet's labelled pixels are a count that changes with every
batch: no fixed shape), and a loss weighting whose ordinary steps are the same device work at every
step (:attr:`~compact_perception.learning.weighting.base.LossWeighting.capturable`: static, single,
MGN in both forms, DWA; GradNorm and UW step their own optimiser with a host-side counter, PCGrad
draws random task orders, CAGrad reads its Gram matrix). Any other run steps eagerly after one
logged line saying why.

The first replay of a run is checked: the state before it is kept, the replayed step's result is
compared bit for bit with the eager step's from the same state (RNG state included); a difference,
or any failure to capture, logs one line and the run goes on eagerly from the eager step's result.
So a captured run gives the bytes of an eager one, as far as one step can show it.

On a CPU nothing is captured; the same buffer path runs uncaptured (:class:`Uncaptured`, which the
tests drive) and gives the eager step's bytes.
"""
from __future__ import annotations

import logging
from typing import Any, Callable, Optional

import torch
from torch import Tensor

from .epoch import prepare_batch, step_on_device, train_step
from .state import RunState

__all__ = ["CapturedStep", "CudaGraph", "Uncaptured", "capture_blocker", "captured_step"]

log = logging.getLogger(__name__)


def capture_blocker(run: RunState) -> Optional[str]:
    """Why ``run``'s training step cannot be captured as a CUDA graph, or None when it can."""
    spec, tp = run.spec, run.spec.params.train
    if spec.device.type != "cuda":
        return f"the device is {spec.device.type}, not CUDA"
    if spec.dist.enabled:
        return "a data-parallel run (torchrun) steps eagerly"
    if tp.compile:
        return "train.compile is on (the compiled forward is not captured)"
    if run.precision == "fp16":
        return "float16's GradScaler reads its scale from the device every step"
    labelled = getattr(run.model, "labelled_maps", ())
    if labelled:
        return (f"{spec.planned.model}'s losses gather its labelled {'/'.join(labelled)} pixels, "
                "a count that changes with every batch")
    if not getattr(run.weighting, "capturable", False):
        return f"the {run.weighting.key} loss weighting's ordinary steps are not the same device work at every step"
    return None


class Uncaptured:
    """A stand-in for :class:`CudaGraph` that captures nothing: each replay runs the step's code
    again, on the same buffers (a CPU run of the buffer path; the tests drive it)."""

    def __init__(self) -> None:
        self.fn: Optional[Callable[[], dict[str, Tensor]]] = None
        self.outputs: dict[str, Tensor] = {}

    def capture(self, fn: Callable[[], dict[str, Tensor]]) -> None:
        self.fn = fn

    def replay(self) -> None:
        assert self.fn is not None
        self.outputs = self.fn()


class CudaGraph:
    """One step captured with ``torch.cuda.graph`` (errors of other threads, a pinning loader's,
    left to them: ``capture_error_mode="thread_local"``); :meth:`replay` reruns its kernels."""

    def __init__(self, device: torch.device) -> None:
        self.device = device
        self.graph: Any = None
        self.outputs: dict[str, Tensor] = {}

    def capture(self, fn: Callable[[], dict[str, Tensor]]) -> None:
        self.graph = None  # the last epoch's graph and its memory go first
        torch.cuda.synchronize(self.device)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph, capture_error_mode="thread_local"):
            self.outputs = fn()
        self.graph = graph

    def replay(self) -> None:
        self.graph.replay()


def _rng_state(device: torch.device) -> Tensor:
    return torch.cuda.get_rng_state(device) if device.type == "cuda" else torch.get_rng_state()


def _set_rng_state(device: torch.device, state: Tensor) -> None:
    if device.type == "cuda":
        torch.cuda.set_rng_state(state, device)
    else:
        torch.set_rng_state(state)


class CapturedStep:
    """The training step of one run, its ordinary steps replayed from a capture (``capturer``: a
    :class:`CudaGraph` on CUDA, :class:`Uncaptured` elsewhere). Called as :func:`~.epoch.train_step`
    is: ``(run, batch, step, n_steps) -> (values, frames)``."""

    def __init__(self, run: RunState, capturer: Any, verify: bool = True) -> None:
        self.run = run
        self.capturer = capturer
        self.verify = verify             # check the first replay against the eager step
        self.buffers: dict[str, Tensor] = {}
        self.mark: Optional[Tensor] = None
        self.key: Optional[tuple] = None
        self.failed: Optional[str] = None
        self.replays = 0

    # ------------------------------------------------------------------ the step
    def __call__(self, run: RunState, batch: dict, step: int, n_steps: int) -> tuple[dict[str, Tensor], int]:
        if self.failed is not None or step == 0 or step == n_steps - 1 or not self._fits(batch):
            return train_step(run, batch, step, n_steps)
        self._fill(batch, step)
        key = self._key()
        if key != self.key:
            if not self._capture(step, n_steps):
                return self._eager_on_buffers(step, n_steps)
            self.key = key
        if self.verify:
            self.verify = False
            if not self._replay_checked(step, n_steps):
                return self._result(self._last_eager)
        else:
            self.capturer.replay()
        self.replays += 1
        return self._result(self.capturer.outputs)

    def _result(self, values: dict[str, Tensor]) -> tuple[dict[str, Tensor], int]:
        frames = self.run.spec.per_rank_batch
        self.run.epoch_sums.n += frames
        return dict(values), frames

    def _fits(self, batch: dict) -> bool:
        """A full batch of the buffers' shapes (a captured step's shapes are fixed)."""
        if "labelled" in batch:
            return False  # labelled pixel lists: a size that changes with every batch
        tensors = {k: v for k, v in batch.items() if isinstance(v, Tensor)}
        if not tensors:
            return False
        if next(iter(tensors.values())).shape[0] != self.run.spec.per_rank_batch:
            return False
        if not self.buffers:
            return True
        return set(tensors) == set(self.buffers) and all(
            t.shape == self.buffers[k].shape and t.dtype == self.buffers[k].dtype for k, t in tensors.items())

    def _fill(self, batch: dict, step: int) -> None:
        """Copy the host's batch and the step index into the fixed buffers (made at the first call)."""
        device = self.run.spec.device
        nb = device.type == "cuda"
        tensors = {k: t for k, t in batch.items() if isinstance(t, Tensor)}  # what to_device moves
        if not self.buffers:
            self.buffers = {k: torch.empty(t.shape, dtype=t.dtype, device=device) for k, t in tensors.items()}
            self.mark = torch.zeros((), dtype=torch.float64, device=device)
        for k, t in tensors.items():
            self.buffers[k].copy_(t, non_blocking=nb)
        self.mark.fill_(float(step))

    def _key(self) -> tuple:
        """What a graph bakes in: the epoch's sums, the weighting's tensors, the learning rates."""
        run = self.run
        tensors = tuple(v for v in vars(run.weighting).values() if isinstance(v, Tensor))
        return (_Same(run.epoch_sums), tuple(_Same(t) for t in tensors),
                tuple(float(g["lr"]) for g in run.optimizer.param_groups))

    def _body(self, step: int, n_steps: int) -> Callable[[], dict[str, Tensor]]:
        run = self.run

        def body() -> dict[str, Tensor]:
            run.optimizer.zero_grad(set_to_none=True)
            return step_on_device(run, prepare_batch(run, self.buffers), step, n_steps, mark=self.mark,
                                  autocast_cache=False)
        return body

    def _eager_on_buffers(self, step: int, n_steps: int) -> tuple[dict[str, Tensor], int]:
        return self._result(self._body(step, n_steps)())

    # ------------------------------------------------------------------ capture and its check
    def _capture(self, step: int, n_steps: int) -> bool:
        for group in self.run.optimizer.param_groups:
            if "capturable" in group:  # Adam: its step counter already lives on the device (fused)
                group["capturable"] = True
        self.run.optimizer._warned_capturable_if_run_uncaptured = True  # its eager steps are meant
        try:
            self.capturer.capture(self._body(step, n_steps))
        except Exception as err:  # noqa: BLE001 - any failure to capture: the run steps eagerly
            first = str(err).splitlines()[0] if str(err) else ""
            self._give_up(f"could not capture it ({type(err).__name__}: {first})")
            return False
        return True

    def _replay_checked(self, step: int, n_steps: int) -> bool:
        """Replay once and compare with the eager step from the same state; keep the eager result."""
        run = self.run
        state = _state_tensors(run)
        before = [t.detach().clone() for t in state]
        rng = _rng_state(run.spec.device)
        self.capturer.replay()
        replayed = [t.detach().clone() for t in state] + [v.clone() for v in self.capturer.outputs.values()]
        for t, b in zip(state, before):
            t.data.copy_(b)
        _set_rng_state(run.spec.device, rng)
        self._last_eager = self._body(step, n_steps)()
        eager = list(state) + list(self._last_eager.values())
        if len(eager) != len(replayed) or not all(
                a.shape == b.shape and torch.equal(a, b) for a, b in zip(replayed, eager)):
            self._give_up("its first replay did not give the eager step's bytes")
            return False
        log.info("%s: training step captured as a CUDA graph (first replay = the eager step, bit for bit)",
                 run.spec.planned.name)
        return True

    def _give_up(self, why: str) -> None:
        self.failed = why
        self.capturer = None
        _not_captured(self.run, why)


def _not_captured(run: RunState, why: str) -> None:
    """The one line a run logs when its step is not captured."""
    log.warning("%s: training step not captured as a CUDA graph: %s; it steps eagerly", run.spec.planned.name, why)


class _Same:
    """Identity, not equality, in a capture key (the object is kept alive, so its id is not reused)."""

    __slots__ = ("obj",)

    def __init__(self, obj: Any) -> None:
        self.obj = obj

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _Same) and other.obj is self.obj

    __hash__ = None  # type: ignore[assignment]


def _state_tensors(run: RunState) -> list[Tensor]:
    """Every tensor a step changes in place: parameters and buffers, the optimiser's state, the
    loss weighting's tensors, the epoch's sums."""
    out = list(run.model.state_dict(keep_vars=True).values())
    for st in run.optimizer.state.values():
        out += [v for v in st.values() if isinstance(v, Tensor)]
    out += [v for v in vars(run.weighting).values() if isinstance(v, Tensor)]
    sums = run.epoch_sums
    out += list(sums.sums.values())
    for at, value in sums._first.values():
        out += [at, value]
    return out


def captured_step(run: RunState) -> Optional[CapturedStep]:
    """The run's captured step per ``train.cuda_graphs`` (``auto``: where :func:`capture_blocker`
    finds nothing, else one logged line and None; ``off``: None)."""
    if run.spec.params.train.cuda_graphs == "off":
        return None
    why = capture_blocker(run)
    if why is not None:
        if run.spec.device.type == "cuda":
            _not_captured(run, why)
        return None
    return CapturedStep(run, CudaGraph(run.spec.device))
