"""The captured training step (learning/training/capture.py, ``train.cuda_graphs``): on a CPU the
buffer path it replays runs uncaptured and gives today's eager step's bytes, epoch after epoch;
a first replay that differs from the eager step falls back with one line and the eager result;
what cannot be captured says why."""
from __future__ import annotations

import contextlib
import dataclasses
import logging

import pytest
import torch

from compact_perception.core import catalog
from compact_perception.core.params import ParamsError, parse_params
from compact_perception.core.plateau_record import NEUTRAL_KEYS
from compact_perception.data.loader import make_loader
from compact_perception.learning.training import distributed as ddp
from compact_perception.learning.training.capture import (CapturedStep, Uncaptured, capture_blocker,
                                                          captured_step)
from compact_perception.learning.training.epoch import epoch_means, train_step
from compact_perception.learning.training.standalone import standalone_run

from repo_params import cap_epochs
from run_fixture import nudged_replay, run_in
from synthetic import make_cache

BATCH, FRAMES, EPOCHS = 2, 10, 3  # 5 steps an epoch: the first and last eager, 3 replayed


def _params(params_dict: dict, precision: str = "fp32", **train):
    cap_epochs(params_dict, EPOCHS)
    params_dict["train"].update(batch_size=BATCH, num_workers=0, device="cpu", precision=precision, **train)
    return parse_params(params_dict)


def _run(params, model, arm, cache, out):
    run = standalone_run(params, run_in(params, model, cache, out, arm=arm), torch.device("cpu"), digest="test")
    loader = make_loader(cache, "train", catalog.MODELS[model].lidar_channels, BATCH, shuffle=False, drop_last=True,
                         labelled=getattr(run.model, "labelled_maps", ()))
    return run, [b for b in loader]


def _train(run, batches, step_fn) -> list:
    """EPOCHS epochs over ``batches`` with ``step_fn``; every step's values, every epoch's means,
    the weights at each epoch's end and the final parameters and optimiser state."""
    out, n = [], len(batches)
    for epoch in range(EPOCHS):
        run.lr = run.lr * (0.5 if epoch == 2 else 1.0)  # a plateau's halving: the graph is captured again
        for group in run.optimizer.param_groups:
            group["lr"] = run.lr
        for step, batch in enumerate(batches):
            values, frames = step_fn(run, batch, step, n)
            out.append(({k: v.clone() for k, v in values.items()}, frames))
        out.append(epoch_means(run))
        out.append(run.weighting.w.clone())
        run.weighting.on_epoch_end(improved=epoch == 0)
    out.append([p.detach().clone() for p in run.model.state_dict().values()])
    out.append([v.clone() for st in run.optimizer.state.values() for v in st.values() if isinstance(v, torch.Tensor)])
    return out


def _same(a, b) -> bool:
    if isinstance(a, torch.Tensor):
        return a.dtype == b.dtype and a.shape == b.shape and torch.equal(a, b)
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b


#: static (SGD), both MGN forms, DWA, the single-task arm, and Chen et al. (fused Adam)
CAPTURABLE = [("compact_15l", None), ("compact_15l_mgn", None), ("compact_15l_mgn_authors", None),
              ("compact_15l", "dwa"), ("compact_15l", "single_ss"), ("chen_bev", None)]


@pytest.mark.parametrize("model, arm", CAPTURABLE, ids=[f"{m}-{a or 'own'}" for m, a in CAPTURABLE])
def test_the_buffer_path_gives_the_eager_steps_bytes(tmp_path, params_dict, model, arm):
    """Three epochs of five steps (the first and last of each eager, the three between through the
    fixed buffers, "captured" again when the epoch's sums, the loss weights or the lr change, the
    first replay checked against the eager step): every step's losses and metrics, every epoch's
    means and weights, the final parameters, buffers and optimiser state are the eager run's bytes."""
    params = _params(params_dict)
    cache = make_cache(tmp_path / "cache", size=16, counts=(FRAMES, 1, 1))
    eager_run, batches = _run(params, model, arm, cache, tmp_path / "eager")
    assert capture_blocker(dataclasses.replace(eager_run, spec=dataclasses.replace(
        eager_run.spec, device=torch.device("cuda")))) is None  # this run would be captured on a GPU
    eager = _train(eager_run, batches, train_step)

    run, _ = _run(params, model, arm, cache, tmp_path / "buffered")
    capturer = FixedMemory(run)
    step = CapturedStep(run, capturer)
    buffered = _train(run, batches, step)
    assert step.failed is None and step.replays == EPOCHS * (len(batches) - 2)
    assert capturer.captures == EPOCHS  # one per epoch (new sums), the lr change falling on a new epoch
    assert capturer.replays >= step.replays
    assert _same(buffered, eager)


class FixedMemory(Uncaptured):
    """The uncaptured replay, holding the step to what a CUDA graph needs of it: every tensor the
    step changes (parameters, buffers, optimiser state, the weighting's tensors, the epoch's sums and
    divergence marks) is the same tensor, at the same address, after a replay as before it, and the
    batch buffers too: a graph replays into the memory it was captured with."""

    def __init__(self, run) -> None:
        super().__init__()
        self.run, self.captures, self.replays = run, 0, 0

    def _memory(self) -> list:
        from compact_perception.learning.training.capture import _state_tensors

        return [(id(t), t.data_ptr()) for t in _state_tensors(self.run)]

    def capture(self, fn) -> None:
        super().capture(fn)
        self.captures += 1

    def replay(self) -> None:
        before = self._memory()
        super().replay()
        assert self._memory() == before, "a replayed step replaced a tensor a graph would hold"
        self.replays += 1


def test_a_replay_that_differs_falls_back_with_one_line(tmp_path, params_dict, caplog):
    """A capture whose replay does not give the eager step's bytes (here: it nudges a weight) is
    caught at its first replay: one warning naming the run, the eager step's result kept, and every
    later step eager; the run's bytes are the eager run's."""
    params = _params(params_dict)
    cache = make_cache(tmp_path / "cache", size=16, counts=(FRAMES, 1, 1))
    eager_run, batches = _run(params, "compact_15l", None, cache, tmp_path / "eager")
    eager = _train(eager_run, batches, train_step)

    run, _ = _run(params, "compact_15l", None, cache, tmp_path / "nudged")
    step = CapturedStep(run, nudged_replay(run))
    with caplog.at_level(logging.WARNING, logger="compact_perception.learning.training.capture"):
        out = _train(run, batches, step)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "not captured as a CUDA graph" in lines[0] and "eager step's bytes" in lines[0]
    assert run.spec.planned.name in lines[0] and "\n" not in lines[0]
    assert step.failed and step.replays == 0
    assert _same(out, eager)


def test_a_capture_that_raises_falls_back_with_one_line(tmp_path, params_dict, caplog):
    params = _params(params_dict)
    cache = make_cache(tmp_path / "cache", size=16, counts=(FRAMES, 1, 1))
    eager_run, batches = _run(params, "compact_15l_mgn", None, cache, tmp_path / "eager")
    eager = _train(eager_run, batches, train_step)

    class Refused(Uncaptured):
        def capture(self, fn) -> None:
            raise RuntimeError("operation not permitted when stream is capturing\nmore detail")

    run, _ = _run(params, "compact_15l_mgn", None, cache, tmp_path / "refused")
    step = CapturedStep(run, Refused())
    with caplog.at_level(logging.WARNING, logger="compact_perception.learning.training.capture"):
        out = _train(run, batches, step)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "could not capture it (RuntimeError: operation not permitted" in lines[0]
    assert "\n" not in lines[0]
    assert _same(out, eager)


def _on_cuda(run, **spec):
    """``run`` as its spec would be on a CUDA device (nothing runs there: the blocker only reads)."""
    return dataclasses.replace(run, spec=dataclasses.replace(run.spec, device=torch.device("cuda"), **spec))


def test_what_cannot_be_captured_says_why(tmp_path, params_dict):
    params = _params(params_dict)
    cache = make_cache(tmp_path / "cache", size=16, counts=(4, 1, 1))
    run, _ = _run(params, "compact_15l", None, cache, tmp_path / "r")
    assert capture_blocker(run) == "the device is cpu, not CUDA"
    assert capture_blocker(_on_cuda(run)) is None
    assert "data-parallel" in capture_blocker(_on_cuda(run, dist=ddp.Dist(world_size=2)))
    assert "float16" in capture_blocker(dataclasses.replace(_on_cuda(run), precision="fp16"))
    polar, _ = _run(params, "polarnet", None, cache, tmp_path / "p")
    assert "labelled ls pixels" in capture_blocker(_on_cuda(polar))
    for arm in ("gradnorm", "uw", "pcgrad", "cagrad"):
        other, _ = _run(params, "compact_15l", arm, cache, tmp_path / arm)
        assert f"the {arm} loss weighting" in capture_blocker(_on_cuda(other))
    compiled = _params(params_dict, compile=True)
    assert "train.compile" in capture_blocker(_on_cuda(run, params=compiled))


def test_a_cpu_run_steps_eagerly_and_says_nothing(tmp_path, params_dict, caplog):
    cache = make_cache(tmp_path / "cache", size=16, counts=(4, 1, 1))
    for setting in ("auto", "off"):
        params = _params(params_dict, cuda_graphs=setting)
        with caplog.at_level(logging.INFO, logger="compact_perception.learning.training.capture"):
            run, _ = _run(params, "compact_15l", None, cache, tmp_path / setting)
        assert run.captured is None and captured_step(run) is None
    assert not caplog.records
    off = _params(params_dict, cuda_graphs="off")
    run, _ = _run(off, "compact_15l", None, cache, tmp_path / "off2")
    assert captured_step(_on_cuda(run, params=off)) is None  # off: never, not even where it could


def test_cuda_graphs_is_a_declared_setting(params_dict):
    params_dict["train"]["cuda_graphs"] = "yes"
    with pytest.raises(ParamsError, match=r"train\.cuda_graphs: .*auto.*off"):
        parse_params(params_dict)
    assert "train.cuda_graphs" in NEUTRAL_KEYS  # a CPU never captures; a GPU only a step equal to eager


# ----------------------------------------------------------------------------- issue 55: the GPU's semantics
def _small(tmp_path, params_dict, model="compact_15l", frames=8):
    """A run of ``model`` and its batches (four steps an epoch: the first and last eager)."""
    params = _params(params_dict)
    cache = make_cache(tmp_path / "cache", size=16, counts=(frames, 1, 1))
    return params, cache, _run(params, model, None, cache, tmp_path / "run")


def test_a_replay_as_far_from_eager_as_eager_is_from_itself_engages(tmp_path, params_dict, monkeypatch, caplog):
    """Issue 55 item 1: a device whose eager step differs from itself in its last bits (a stand-in
    for the bilinear upsampling's atomic CUDA backward: every run of the step moves each parameter by
    its own relative 1e-7, about an ulp) still captures, and a replay far outside that still falls back."""
    from compact_perception.learning.training import capture as capture_mod

    noise = torch.Generator().manual_seed(1)  # not the run's RNG, which the check puts back
    real = capture_mod.step_on_device

    def atomic(run, *a, **k):
        out = real(run, *a, **k)
        with torch.no_grad():
            for p in run.model.parameters():
                p.mul_(1 + torch.randn(p.shape, generator=noise) * 1e-7)
        return out

    monkeypatch.setattr(capture_mod, "step_on_device", atomic)
    params, cache, (run, batches) = _small(tmp_path, params_dict)
    step = CapturedStep(run, Uncaptured())
    with caplog.at_level(logging.WARNING, logger="compact_perception.learning.training.capture"):
        for k, batch in enumerate(batches):
            step(run, batch, k, len(batches))
    assert step.failed is None and step.replays == len(batches) - 2 and not caplog.records

    run2, _ = _run(params, "compact_15l", None, cache, tmp_path / "nudged")
    step2 = CapturedStep(run2, nudged_replay(run2))
    for k, batch in enumerate(batches):
        step2(run2, batch, k, len(batches))
    assert step2.failed and "two eager runs of it differ by" in step2.failed and step2.replays == 0


def test_replay_difference_is_bytes_where_eager_is_deterministic():
    from compact_perception.learning.training.capture import replay_difference

    a = [torch.tensor([1.0, 2.0]), torch.tensor(3)]
    up = lambda x, n: x if n == 0 else up(torch.nextafter(x, torch.tensor(9.0)), n - 1)  # noqa: E731  n ulps up
    near = [torch.tensor([1.0, float(up(torch.tensor(2.0), 3))]), torch.tensor(3)]
    assert replay_difference(a, a, a) is None
    assert "eager step's bytes" in replay_difference(near, a, a)  # the two eager runs agree: bytes
    spread = [torch.tensor([1.0, float(up(torch.tensor(2.0), 1))]), torch.tensor(3)]
    assert replay_difference(near, a, spread) is None               # within 4x the eager runs' spread
    assert "differ by" in replay_difference([torch.tensor([1.0, 2.1]), torch.tensor(3)], a, spread)
    assert "agree on" in replay_difference([torch.tensor([1.0, 2.0]), torch.tensor(4)], a, spread)


class FakeCuda:
    """torch.cuda's streams, graphs and caching allocator as torch 2.13 runs them, for a CPU: a
    capture that an error invalidates makes ``capture_end`` raise "operation failed due to a previous
    error during capture" before it gives the allocator its pool back (a build without the allocator
    fix), after which ``empty_cache`` asserts; work queued during a capture does run (the CPU)."""

    class Stream:
        def __init__(self, device=None, name="side") -> None:
            self.name = name

        def wait_stream(self, other) -> None:
            pass

    def __init__(self, monkeypatch) -> None:
        self.default = FakeCuda.Stream(name="default")
        self.current = self.default
        self.capturing = None       # the stream a capture is under way on
        self.invalidated = False    # an error happened inside the capture
        self.pools: list = []       # pools the allocator routes to
        self.calls: list = []       # (what, stream, capturing) of every step body
        fake = self

        class Graph:
            def __init__(self) -> None:
                self.ended = False

            def capture_begin(self, pool=None, capture_error_mode="global", **_) -> None:
                assert fake.capturing is None, "a capture is already under way"
                fake.capturing, fake.invalidated = fake.current, False
                fake.pools.append(self.pool())

            def capture_end(self) -> None:
                assert fake.current is fake.capturing, "Capture must end on the same stream it began on"
                fake.capturing = None
                if fake.invalidated:
                    raise RuntimeError("CUDA error: operation failed due to a previous error during capture")
                fake.pools.remove(self.pool())
                self.ended = True

            def pool(self):
                return (0, id(self))

            def replay(self) -> None:
                assert self.ended

            def reset(self) -> None:
                pass

        def end_pool(device, pool) -> None:
            if pool not in fake.pools:
                raise RuntimeError("endAllocatePool: not currently recording to mempool_id")
            fake.pools.remove(pool)

        def empty_cache() -> None:
            assert not fake.pools, "captures_underway.empty() INTERNAL ASSERT FAILED"

        @contextlib.contextmanager
        def stream(s):
            prev, fake.current = fake.current, s
            try:
                yield
            finally:
                fake.current = prev

        def set_stream(s) -> None:
            fake.current = s

        for name, value in {"Stream": FakeCuda.Stream, "CUDAGraph": Graph, "empty_cache": empty_cache,
                            "synchronize": lambda device=None: None, "stream": stream, "set_stream": set_stream,
                            "current_stream": lambda device=None: fake.current, "current_device": lambda: 0}.items():
            monkeypatch.setattr(torch.cuda, name, value)
        monkeypatch.setattr(torch._C, "_cuda_endAllocateToPool", end_pool, raising=False)
        monkeypatch.setattr(torch._C, "_host_emptyCache", lambda: None, raising=False)
        monkeypatch.setattr(torch.cuda.graph, "default_capture_stream", None)

    def failing_step(self, monkeypatch, fail: bool):
        """The step's device work: recorded, and (``fail``) refused inside a capture."""
        from compact_perception.learning.training import capture as capture_mod

        real = self.real = getattr(self, "real", capture_mod.step_on_device)

        def step(run, *a, **k):
            self.calls.append((self.current, self.capturing is not None))
            if fail and self.capturing is not None:
                self.invalidated = True
                raise RuntimeError("CUDA error: operation not permitted when stream is capturing\nmore")
            return real(run, *a, **k)

        monkeypatch.setattr(capture_mod, "step_on_device", step)


def test_a_failed_capture_leaves_the_process_as_it_was(tmp_path, params_dict, monkeypatch, caplog):
    """Issue 55 item 5: an error inside the capture (stand-in: the step refuses to run while a capture
    is under way) is the cause the log line gives, not capture_end's "previous error"; the current
    stream is the default one again, the allocator takes no more allocations into the graph's pool
    (``empty_cache`` works), and the next run in the process captures."""
    from compact_perception.learning.training.capture import CudaGraph

    cuda = FakeCuda(monkeypatch)
    cuda.failing_step(monkeypatch, fail=True)
    params, cache, (run, batches) = _small(tmp_path, params_dict)
    step = CapturedStep(run, CudaGraph(torch.device("cpu")), verify=False)
    with caplog.at_level(logging.WARNING, logger="compact_perception.learning.training.capture"):
        step(run, batches[0], 0, len(batches))
        step(run, batches[1], 1, len(batches))
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "operation not permitted when stream is capturing" in lines[0], lines
    assert "previous error" not in lines[0] and step.failed
    assert cuda.current is cuda.default and cuda.capturing is None and not cuda.pools
    torch.cuda.empty_cache()

    cuda.failing_step(monkeypatch, fail=False)  # the worker's next run
    run2, _ = _run(params, "compact_15l", None, cache, tmp_path / "next")
    step2 = CapturedStep(run2, CudaGraph(torch.device("cpu")), verify=False)
    step2(run2, batches[0], 0, len(batches))
    step2(run2, batches[1], 1, len(batches))
    assert step2.failed is None and step2.replays == 1 and cuda.current is cuda.default


def test_the_first_capture_is_warmed_up_on_its_stream(tmp_path, params_dict, monkeypatch):
    """Issue 55 item 8: before a run's first capture the step runs eagerly on the stream it is then
    captured on (PyTorch's whole-network example), and the run's state is put back after it."""
    from compact_perception.learning.training.capture import CudaGraph, _state_tensors

    cuda = FakeCuda(monkeypatch)
    cuda.failing_step(monkeypatch, fail=False)
    _, _, (run, batches) = _small(tmp_path, params_dict)
    graph = CudaGraph(torch.device("cpu"))
    step = CapturedStep(run, graph, verify=False)
    step(run, batches[0], 0, len(batches))
    cuda.calls.clear()
    warm = {}

    real_capture = graph.capture

    def capture(fn):
        warm["state"] = [t.detach().clone() for t in _state_tensors(run)]
        real_capture(fn)

    graph.capture = capture
    before = [t.detach().clone() for t in _state_tensors(run)]
    step(run, batches[1], 1, len(batches))
    (warm_stream, warm_capturing), (cap_stream, cap_capturing) = cuda.calls[:2]
    assert warm_stream is cap_stream is graph.stream and warm_stream is not cuda.default
    assert not warm_capturing and cap_capturing
    assert all(torch.equal(a, b) for a, b in zip(warm["state"], before))  # the warm-up left no trace
    assert cuda.current is cuda.default
