"""The captured training step (learning/training/capture.py, ``train.cuda_graphs``): on a CPU the
buffer path it replays runs uncaptured and gives today's eager step's bytes, epoch after epoch;
a first replay that differs from the eager step falls back with one line and the eager result;
what cannot be captured says why."""
from __future__ import annotations

import dataclasses
import logging

import pytest
import torch

from compact_perception.core import catalog
from compact_perception.core.config import ParamsError, parse_params
from compact_perception.core.plateau_record import NEUTRAL_KEYS
from compact_perception.data.loader import make_loader
from compact_perception.learning.training import distributed as ddp
from compact_perception.learning.training import train as train_mod
from compact_perception.learning.training.capture import (CapturedStep, Uncaptured, capture_blocker,
                                                          captured_step)
from compact_perception.learning.training.epoch import epoch_means, train_step
from compact_perception.learning.training.state import RunSpec

from repo_params import cap_epochs
from run_fixture import run_in
from synthetic import make_cache

BATCH, FRAMES, EPOCHS = 2, 10, 3  # 5 steps an epoch: the first and last eager, 3 replayed


def _params(params_dict: dict, precision: str = "fp32", **train):
    cap_epochs(params_dict, EPOCHS)
    params_dict["train"].update(batch_size=BATCH, num_workers=0, device="cpu", precision=precision, **train)
    return parse_params(params_dict)


def _run(params, model, arm, cache, out):
    from compact_perception.core.cache import read_meta

    spec = RunSpec(params, run_in(params, model, cache, out, arm=arm), torch.device("cpu"), ddp.Dist(), 0, "test",
                   params.train.batch_size, len(read_meta(cache)["seg_classes"]), progress=False)
    run = train_mod._setup(spec)
    run.model.train()
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

    class Nudged(Uncaptured):
        def replay(self) -> None:
            super().replay()
            with torch.no_grad():
                p = next(run.model.parameters())
                p[(0,) * p.dim()] += 1e-3

    run, _ = _run(params, "compact_15l", None, cache, tmp_path / "nudged")
    step = CapturedStep(run, Nudged())
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
