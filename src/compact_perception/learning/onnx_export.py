"""ONNX export of the compact model and ONNX Runtime timing (issue 15).

The compact model's forward takes a dict batch (``rgb``, ``dvs`` when the dataset has DVS,
``lidar``) and returns a dict (``de``, ``ss``, ``ls``, ``bevp``). :class:`OnnxWrapper` gives it
positional tensor inputs and a tuple of outputs so the graph gets named inputs and outputs.

- :func:`export_onnx` writes the model as ONNX (the TorchScript-based exporter,
  ``dynamo=False``: it runs offline and needs neither ``onnxscript`` nor ``torch.export``),
  then runs the file in ONNX Runtime on the same inputs and reports the largest absolute
  difference to PyTorch's outputs, per output.
- :func:`onnxruntime_latency` is the median batch-1 latency of an ONNX file in ONNX Runtime
  (CPU execution provider; warm-up calls excluded).

The model is exported from a float32, eval-mode, CPU deep copy: the caller's model (its mode,
device, dtype, memory format) is left untouched. Batch and spatial sizes are fixed (the
exported graph is for the example's shapes).
"""
from __future__ import annotations

import copy
import logging
import statistics
import time
import warnings
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import torch
from torch import Tensor, nn

log = logging.getLogger(__name__)

#: ONNX opset of the exported graphs (bilinear ``Resize`` with ``align_corners`` needs >= 11).
OPSET = 17
__all__ = ["OPSET", "OnnxWrapper", "export_onnx", "onnx_session", "onnxruntime_latency"]


class OnnxWrapper(nn.Module):
    """``forward(*tensors) -> tuple`` around a dict-in / dict-out model: positional inputs
    ``input_names`` are packed into the batch dict, outputs ``output_names`` returned in order."""

    def __init__(self, model: nn.Module, input_names: Sequence[str], output_names: Sequence[str]) -> None:
        super().__init__()
        self.model = model
        self.input_names = tuple(input_names)
        self.output_names = tuple(output_names)

    def forward(self, *tensors: Tensor) -> tuple[Tensor, ...]:
        out = self.model(dict(zip(self.input_names, tensors)))
        return tuple(out[k] for k in self.output_names)


def _input_names(model: nn.Module, batch: Mapping[str, Tensor]) -> list[str]:
    """The batch keys the compact model reads, in graph order: ``rgb``, ``dvs`` (when the model
    has DVS: ``model.has_dvs``, default = present in the batch), ``lidar``."""
    names = ["rgb", "dvs", "lidar"]
    if not getattr(model, "has_dvs", "dvs" in batch):
        names.remove("dvs")
    missing = [k for k in names if k not in batch]
    if missing:
        raise KeyError(f"example batch lacks {missing}; has {sorted(batch)}")
    return names


def onnx_session(path: str | Path, threads: int | None = None) -> Any:
    """An ONNX Runtime ``InferenceSession`` on the CPU execution provider; ``threads`` intra-op
    threads (default ``torch.get_num_threads()``, so both runtimes use the same cores), one
    inter-op thread, no spin-waiting, all graph optimisations, sequential execution."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = int(threads or torch.get_num_threads())
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.log_severity_level = 3
    # idle worker threads sleep instead of spinning: a spinning pool would take the cores from
    # PyTorch when the two runtimes are timed one after the other
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return ort.InferenceSession(str(path), sess_options=so, providers=["CPUExecutionProvider"])


def export_onnx(model: nn.Module, example_batch: Mapping[str, Tensor], path: str | Path, *,
                opset: int = OPSET, input_names: Sequence[str] | None = None,
                output_names: Sequence[str] | None = None) -> dict[str, Any]:
    """Write ``model`` (dict batch -> dict of tensors) as ONNX to ``path`` and check it.

    Exports a float32 eval-mode CPU copy with the TorchScript exporter (``dynamo=False``,
    ``opset``, constant folding), for the shapes of ``example_batch``; inputs ``input_names``
    (default: the compact model's ``rgb``, ``dvs`` if it has DVS, ``lidar``), outputs
    ``output_names`` (default: every tensor the forward returns, in its order); the file is written to a
    temporary name and renamed, so ``path`` is never half-written. The file is then loaded in
    ONNX Runtime (CPU) and run on ``example_batch``; PyTorch runs the same copy on the same
    inputs. Returns ``path``, ``inputs``, ``outputs``, ``opset``, ``max_abs_diff`` (output ->
    float), ``max_abs_diff_all``, ``onnx`` and ``onnxruntime`` versions and ``size_mb``.
    """
    import onnx
    import onnxruntime

    path = Path(path)
    net = copy.deepcopy(model).to(device="cpu", dtype=torch.float32,
                                  memory_format=torch.contiguous_format).eval()
    batch = {k: v.detach().to("cpu", torch.float32).contiguous() for k, v in example_batch.items()
             if isinstance(v, Tensor)}
    in_names = list(input_names) if input_names is not None else _input_names(net, batch)
    with torch.inference_mode():
        ref = net(batch)
    out_names = list(output_names) if output_names is not None else [k for k, v in ref.items() if isinstance(v, Tensor)]
    wrapper = OnnxWrapper(net, in_names, out_names).eval()
    args = tuple(batch[k] for k in in_names)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the legacy exporter's deprecation and tracer notes
            torch.onnx.export(wrapper, args, str(tmp), input_names=in_names, output_names=out_names,
                              opset_version=opset, do_constant_folding=True, dynamo=False)
        onnx.checker.check_model(str(tmp))
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    sess = onnx_session(path)
    got = sess.run(out_names, {k: batch[k].numpy() for k in in_names})
    diffs = {k: float(np.max(np.abs(g - ref[k].numpy()))) if g.size else 0.0 for k, g in zip(out_names, got)}
    result = {
        "path": str(path), "inputs": in_names, "outputs": out_names, "opset": opset,
        "max_abs_diff": diffs, "max_abs_diff_all": max(diffs.values()) if diffs else 0.0,
        "onnx": onnx.__version__, "onnxruntime": onnxruntime.__version__,
        "size_mb": path.stat().st_size / 2**20,
    }
    log.info("exported %s (%s -> %s), max |onnxruntime - torch| = %.3g", path, ",".join(in_names),
             ",".join(out_names), result["max_abs_diff_all"])
    return result


def onnxruntime_latency(path: str | Path, inputs: Mapping[str, Any], warmup: int = 10, runs: int = 50,
                        *, threads: int | None = None, return_all: bool = False) -> float | list[float]:
    """Median latency in seconds of one ONNX Runtime call on ``inputs`` (name -> array or tensor;
    extra names are ignored), after ``warmup`` untimed calls; ``return_all`` gives every timed
    latency instead. ONNX Runtime's CPU ``run`` is synchronous, so the clock reads finished work."""
    if runs < 1:
        raise ValueError(f"runs must be at least 1, got {runs}")
    if warmup < 0:
        raise ValueError(f"warmup must be >= 0, got {warmup}")
    sess = onnx_session(path, threads)
    names = [i.name for i in sess.get_inputs()]
    missing = [n for n in names if n not in inputs]
    if missing:
        raise KeyError(f"{path}: inputs {missing} missing; given {sorted(inputs)}")
    feed = {}
    for n in names:
        v = inputs[n]
        feed[n] = v.detach().float().cpu().contiguous().numpy() if isinstance(v, Tensor) else np.ascontiguousarray(v, np.float32)
    for _ in range(warmup):
        sess.run(None, feed)
    times: list[float] = []
    for _ in range(runs):
        t0 = time.perf_counter()
        sess.run(None, feed)
        times.append(time.perf_counter() - t0)
    return times if return_all else statistics.median(times)
