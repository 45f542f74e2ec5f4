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

Before a run's first capture the step runs once eagerly on the capture stream, from the run's
state, which is then put back (PyTorch's whole-network example warms up on the side stream it
captures on: lazily made handles and workspaces are made outside the capture).

The first replay of a run is checked against what the device itself does (:func:`replay_difference`):
the state before it is kept, the step is replayed, then run eagerly twice from that same state (RNG
state included); the run goes on from the second eager run. Where the two eager runs agree bit for
bit (every CPU; a GPU step without atomic adds) the replay must give the same bytes. Where they do
not (the bilinear upsampling's CUDA backward adds with atomics, so two eager runs of one step differ
in their last bits), each tensor of the replay must be within :data:`SPREAD_SLACK` times the two
eager runs' difference in that tensor, or :data:`REPLAY_RTOL` of its largest value: a replay as far
from the eager step as the eager step is from itself. A larger difference, or any failure to
capture, logs one line and the run goes on eagerly from the eager step's result.

A capture that fails is contained (:meth:`CudaGraph.capture`): the capture is ended and its graph
dropped, the allocator no longer routes to the graph's pool, the current stream is put back, and
the log line names the error raised inside the capture, not the one ``capture_end`` raises after it
(``torch.cuda.graph.__exit__`` has no ``try/finally`` in torch 2.13, so it is not used).

On a CPU nothing is captured; the same buffer path runs uncaptured (:class:`Uncaptured`, which the
tests drive) and gives the eager step's bytes.
"""
from __future__ import annotations

import contextlib
import logging
from typing import Any, Callable, Optional, Sequence

import torch
from torch import Tensor

from .epoch import prepare_batch, step_on_device, train_step
from .state import RunState

__all__ = ["REPLAY_RTOL", "SPREAD_SLACK", "CapturedStep", "CudaGraph", "Uncaptured", "capture_blocker",
           "captured_step", "replay_difference"]

log = logging.getLogger(__name__)

#: Where two eager runs of a step differ (atomic adds), how many times their difference in a tensor a
#: replay may be from the eager run in it: the replay's own atomic order is a third draw, as likely to
#: fall farther from the eager run than the second eager run did as nearer.
SPREAD_SLACK = 4.0
#: Where two eager runs of a step differ, the least difference allowed in any tensor, relative to its
#: largest absolute value (about 8 float32 ulps): a tensor whose two eager runs happened to agree.
REPLAY_RTOL = 1e-6


def replay_difference(replayed: Sequence[Tensor], eager: Sequence[Tensor], again: Sequence[Tensor]) -> Optional[str]:
    """Why ``replayed`` is not ``eager`` as far as the device can tell, or None when it is.

    ``eager`` and ``again``: the same tensors from two eager runs of the same work from the same state.
    Where they agree bit for bit (a deterministic device: every CPU), ``replayed`` must equal ``eager``
    bit for bit. Where they differ anywhere (a GPU's atomic adds), each floating tensor of
    ``replayed`` may differ from ``eager``'s by at most ``max(SPREAD_SLACK * spread, REPLAY_RTOL *
    max|eager|)``, ``spread`` the largest difference of the two eager runs in that tensor; other
    tensors (counters, indices) and NaNs' places must be equal."""
    if not len(replayed) == len(eager) == len(again):
        return f"{len(replayed)} tensors against the eager step's {len(eager)}"
    for x, e in zip(replayed, eager):
        if x.shape != e.shape or x.dtype != e.dtype:
            return f"a {x.dtype} {tuple(x.shape)} tensor where the eager step has {e.dtype} {tuple(e.shape)}"
    if all(torch.equal(e, g) for e, g in zip(eager, again)):  # a deterministic device: the bytes
        if all(torch.equal(x, e) for x, e in zip(replayed, eager)):
            return None
        return "its first replay did not give the eager step's bytes (two eager runs of it do)"
    for x, e, g in zip(replayed, eager, again):
        if torch.equal(x, e):
            continue
        if not e.is_floating_point() or not torch.equal(torch.isnan(x), torch.isnan(e)):
            return "its first replay differs from the eager step in a tensor two eager runs agree on"
        xd, ed, gd = (torch.nan_to_num(t.detach().double(), nan=0.0) for t in (x, e, g))
        gap, spread = float((xd - ed).abs().max()), float((gd - ed).abs().max())
        allowed = max(SPREAD_SLACK * spread, REPLAY_RTOL * float(ed.abs().max()))
        if not gap <= allowed:
            return (f"its first replay differs from the eager step by {gap:.3g} in a tensor where two eager "
                    f"runs of it differ by {spread:.3g} (allowed {allowed:.3g})")
    return None


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

    def warm_up(self, fn: Callable[[], dict[str, Tensor]]) -> None:
        fn()

    def capture(self, fn: Callable[[], dict[str, Tensor]]) -> None:
        self.fn = fn

    def replay(self) -> None:
        assert self.fn is not None
        self.outputs = self.fn()


class CudaGraph:
    """One step captured as a ``torch.cuda.CUDAGraph`` on a side stream of its own (errors of other
    threads, a pinning loader's, left to them: ``capture_error_mode="thread_local"``); :meth:`replay`
    reruns its kernels. The capture is driven here, not through ``torch.cuda.graph``, so that a
    failure inside it leaves the process as it was (:meth:`capture`)."""

    def __init__(self, device: torch.device) -> None:
        self.device = device
        self.graph: Any = None
        self.outputs: dict[str, Tensor] = {}
        self.stream: Any = None  # the side stream of the warm-up and every capture (made at first use)

    def _side_stream(self) -> Any:
        if self.stream is None:
            self.stream = torch.cuda.Stream(self.device)
        return self.stream

    @contextlib.contextmanager
    def _on_side_stream(self):
        """The side stream as the current stream, after the work queued before it; the previous
        stream back afterwards, whatever happened, and waiting for the side stream's work."""
        side, prev = self._side_stream(), torch.cuda.current_stream(self.device)
        side.wait_stream(prev)
        torch.cuda.set_stream(side)
        try:
            yield side
        finally:
            torch.cuda.set_stream(prev)
            prev.wait_stream(side)

    def warm_up(self, fn: Callable[[], dict[str, Tensor]]) -> None:
        """Run ``fn`` eagerly on the stream the capture will use (before a run's first capture)."""
        with self._on_side_stream():
            fn()

    def capture(self, fn: Callable[[], dict[str, Tensor]]) -> None:
        """Capture ``fn`` (as ``torch.cuda.graph`` does: synchronise, free the allocator's cache,
        begin on the side stream). An error inside the capture propagates as it was raised; before it
        does, the capture is ended (its own error, "operation failed due to a previous error during
        capture", dropped), the allocator stops routing to the graph's pool where ``capture_end`` did
        not get that far, the graph is dropped and the current stream put back."""
        self.graph = None  # the last epoch's graph and its memory go first
        torch.cuda.synchronize(self.device)
        torch.cuda.empty_cache()
        graph = torch.cuda.CUDAGraph()
        with self._on_side_stream():
            capturing = False
            try:
                graph.capture_begin(capture_error_mode="thread_local")
                capturing = True
                outputs = fn()
                capturing = False
                graph.capture_end()
            except BaseException:
                if capturing:
                    _end_failed_capture(graph, self.device)
                with contextlib.suppress(Exception):
                    graph.reset()
                raise
        self.outputs = outputs
        self.graph = graph

    def replay(self) -> None:
        self.graph.replay()


def _end_failed_capture(graph: Any, device: torch.device) -> None:
    """End a capture that an error interrupted, so that the process can go on: ``capture_end`` ends
    the stream's capture (and raises, the capture being invalid); where it raised before giving the
    allocator its pool back, the pool is ended here (an error if it was given back: dropped)."""
    try:
        graph.capture_end()
    except Exception:  # noqa: BLE001 - the consequence of the error being raised, not news
        index = device.index if device.index is not None else torch.cuda.current_device()
        with contextlib.suppress(Exception):
            torch._C._cuda_endAllocateToPool(index, graph.pool())


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
        self.warmed = False              # the step ran once on the capture stream before the first capture

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
            self.replays += 1
            return self._result(self._last_eager)  # the state is the eager run's: so are the values
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
            if not self.warmed and hasattr(self.capturer, "warm_up"):
                self.warmed = True
                self._from_state_kept(lambda: self.capturer.warm_up(self._body(step, n_steps)))
            self.capturer.capture(self._body(step, n_steps))
        except Exception as err:  # noqa: BLE001 - any failure to capture: the run steps eagerly
            first = str(err).splitlines()[0] if str(err) else ""
            self._give_up(f"could not capture it ({type(err).__name__}: {first})")
            return False
        return True

    def _from_state_kept(self, fn: Callable[[], Any]) -> list[Tensor]:
        """Run ``fn`` and put the run's state and RNG back as they were; what it left in the state
        (cloned) is returned."""
        run = self.run
        state = _state_tensors(run)
        before = [t.detach().clone() for t in state]
        rng = _rng_state(run.spec.device)
        try:
            fn()
            return [t.detach().clone() for t in state]
        finally:
            for t, b in zip(state, before):
                t.data.copy_(b)
            _set_rng_state(run.spec.device, rng)

    def _replay_checked(self, step: int, n_steps: int) -> bool:
        """Replay once, then run the step eagerly twice from the same state; the replay must be as
        close to the second eager run as the device allows (:func:`replay_difference`, the first
        eager run giving the device's own spread). The second eager run's state and values stay."""
        run, body = self.run, self._body(step, n_steps)
        outputs: dict[str, list[Tensor]] = {}

        def replay() -> None:
            self.capturer.replay()
            outputs["replayed"] = [v.clone() for v in self.capturer.outputs.values()]

        def eager() -> None:
            outputs["again"] = [v.clone() for v in body().values()]

        replayed = self._from_state_kept(replay) + outputs["replayed"]
        again = self._from_state_kept(eager) + outputs["again"]
        self._last_eager = body()
        why = replay_difference(replayed, list(_state_tensors(run)) + list(self._last_eager.values()), again)
        if why is not None:
            self._give_up(why)
            return False
        log.info("%s: training step captured as a CUDA graph (first replay = the eager step, as far as two "
                 "eager runs of it agree)", run.spec.planned.name)
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
