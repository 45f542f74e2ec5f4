"""Model efficiency (paper Table III, SPEC 8): parameters, size, peak memory, FPS at batch 1.

Methods (stated in every result so the report can quote them):

- **parameters**: ``sum(p.numel())`` over ``model.parameters()``.
- **size**: the ``state_dict`` serialised with ``torch.save`` into memory; ``len(bytes) / 2**20``
  (MiB, printed as "MB" as in the paper). Buffers (BatchNorm statistics) are included.
- **peak memory at batch 1**:
  on CUDA, ``torch.cuda.max_memory_allocated`` over one inference forward after
  ``reset_peak_memory_stats`` (model weights + input + activations held by the caching
  allocator; the CUDA context, which ``nvidia-smi`` and probably the paper's "GPU usage" include,
  is not counted);
  on CPU, an analytic count with forward hooks: bytes of parameters and buffers + input tensors +
  every tensor output by every module (the model itself included) during one forward, each
  underlying storage counted once (views and in-place results share one). It is an upper bound
  of the live activations (nothing is assumed freed; intermediates not produced by a module,
  e.g. a ``torch.cat`` inside ``forward``, are missed), deterministic and allocator-independent.
- **speed**: :func:`measure_fps` -- ``warmup`` untimed calls, then ``runs`` timed calls, each
  bracketed by device synchronisation (``torch.cuda.synchronize`` on CUDA) so the clock reads
  finished work; the **median** latency gives FPS = 1000 / median_ms.
- **ONNX Runtime** (issue 15, compact models): :func:`measure_onnx` exports the network to ONNX
  (:func:`compact_perception.learning.onnx_export.export_onnx`, a temporary file), checks ONNX Runtime's
  outputs against PyTorch's (max abs difference) and times ONNX Runtime's CPU execution
  provider at batch 1 the same way (warm-up excluded, median; ``run`` is synchronous), with
  as many intra-op threads as PyTorch uses.
"""
from __future__ import annotations

import io as _io
import logging
import statistics
import time
from typing import Any, Callable, Mapping, Union

import torch
from torch import Tensor, nn

log = logging.getLogger(__name__)

Batch = Mapping[str, Tensor]
ModelLike = Union[nn.Module, Callable[[Any], Any]]

CPU_MEMORY_METHOD = "forward hooks: bytes of parameters, buffers, input and every module output, each storage once (upper bound)"
CUDA_MEMORY_METHOD = "torch.cuda.max_memory_allocated during one forward (weights + activations; no CUDA context)"


def device_name(device: torch.device | str) -> str:
    """``"NVIDIA ..."`` (the CUDA device name) or ``"CPU (N threads)"``."""
    device = torch.device(device)
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    return f"CPU ({torch.get_num_threads()} threads)"


def synchronize(device: torch.device | str) -> None:
    """Wait for queued work on ``device`` (no-op on CPU)."""
    device = torch.device(device)
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def count_params(model: nn.Module) -> int:
    """Number of parameters (trainable or not)."""
    return int(sum(p.numel() for p in model.parameters()))


def state_dict_size_mb(model: nn.Module) -> float:
    """Size of the serialised ``state_dict`` in MiB (``len(bytes) / 2**20``)."""
    buf = _io.BytesIO()
    torch.save(model.state_dict(), buf)
    return len(buf.getvalue()) / 2**20


def _storages(obj: Any, out: dict[int, Any]) -> None:
    """Collect ``storage data_ptr -> storage`` of every tensor in ``obj`` (views and in-place
    results share a storage and are counted once). The storages are kept referenced until the
    count is done, so a freed block cannot be reused at the same address and hide a tensor."""
    if isinstance(obj, Tensor):
        st = obj.untyped_storage()
        out.setdefault(st.data_ptr(), st)
    elif isinstance(obj, Mapping):
        for v in obj.values():
            _storages(v, out)
    elif isinstance(obj, (list, tuple)):
        for v in obj:
            _storages(v, out)


def _call(model: ModelLike, batch: Any) -> Any:
    return model(batch)


def peak_memory_mb(model: nn.Module, batch: Batch, device: torch.device | str) -> tuple[float, str]:
    """Peak memory of one batch-1 inference forward in MiB and the method used (module doc)."""
    device = torch.device(device)
    model.eval()
    if device.type == "cuda":
        synchronize(device)
        torch.cuda.reset_peak_memory_stats(device)
        with torch.inference_mode():
            _call(model, batch)
        synchronize(device)
        return torch.cuda.max_memory_allocated(device) / 2**20, CUDA_MEMORY_METHOD
    seen: dict[int, Any] = {}
    _storages(list(model.parameters()) + list(model.buffers()), seen)
    _storages(batch, seen)

    def hook(_m: nn.Module, _inp: Any, out: Any) -> None:
        _storages(out, seen)

    handles = [m.register_forward_hook(hook) for m in model.modules()]
    try:
        with torch.inference_mode():
            _call(model, batch)
    finally:
        for h in handles:
            h.remove()
    total = sum(st.nbytes() for st in seen.values())
    seen.clear()
    return total / 2**20, CPU_MEMORY_METHOD


def measure_fps(model_fn_or_module: ModelLike, batch: Any, device: torch.device | str,
                warmup: int = 10, runs: int = 50) -> dict[str, Any]:
    """Batch-1 inference speed: median latency over ``runs`` timed calls after ``warmup``
    untimed ones; the device is synchronised before each clock read.

    ``model_fn_or_module`` is an ``nn.Module`` (put in eval mode, run under
    ``torch.inference_mode``) or any callable taking ``batch``. The batch must already be on
    ``device``. Returns ``fps`` (1000 / median ms), ``latency_ms`` (median), ``latency_ms_mean``,
    ``latency_ms_min``, ``latency_ms_p90``, ``warmup``, ``runs``, ``device``.
    """
    if runs < 1:
        raise ValueError(f"runs must be at least 1, got {runs}")
    if warmup < 0:
        raise ValueError(f"warmup must be >= 0, got {warmup}")
    device = torch.device(device)
    fn = model_fn_or_module
    if isinstance(fn, nn.Module):
        fn.eval()
    times_ms: list[float] = []
    with torch.inference_mode():
        for _ in range(warmup):
            _call(fn, batch)
        synchronize(device)
        for _ in range(runs):
            synchronize(device)
            t0 = time.perf_counter()
            _call(fn, batch)
            synchronize(device)
            times_ms.append((time.perf_counter() - t0) * 1e3)
    med = statistics.median(times_ms)
    srt = sorted(times_ms)
    return {
        "fps": 1e3 / med if med > 0 else float("inf"),
        "latency_ms": med,
        "latency_ms_mean": statistics.fmean(times_ms),
        "latency_ms_min": srt[0],
        "latency_ms_p90": srt[min(len(srt) - 1, int(round(0.9 * (len(srt) - 1))))],
        "warmup": warmup,
        "runs": runs,
        "device": device_name(device),
    }


def measure_onnx(model: nn.Module, batch: Batch, warmup: int = 10, runs: int = 50,
                 pytorch_cpu_latency_ms: float | None = None) -> dict[str, Any]:
    """ONNX Runtime batch-1 CPU figures of ``model`` (module doc): ``onnx_fps``,
    ``onnx_latency_ms`` (median), ``onnx_latency_ms_min``, ``onnx_max_abs_diff`` (largest
    |ONNX Runtime - PyTorch| over the outputs), ``onnx_device``, ``onnxruntime`` and ``onnx_opset``;
    with ``pytorch_cpu_latency_ms`` (PyTorch's batch-1 CPU median latency, same threads) also
    ``onnx_speedup`` = PyTorch latency / ONNX Runtime latency. Without ``onnxruntime``
    installed, or if the export fails, returns ``{"onnx_error": reason}``."""
    import tempfile
    from pathlib import Path

    try:
        from ..learning.onnx_export import export_onnx, onnxruntime_latency

        with tempfile.TemporaryDirectory(prefix="onnx_bench_") as tmp:
            path = Path(tmp) / "model.onnx"
            info = export_onnx(model, batch, path)
            times = onnxruntime_latency(path, batch, warmup, runs, return_all=True)
    except Exception as err:  # noqa: BLE001 - the PyTorch figures stand without ONNX ones
        log.warning("%s: no ONNX Runtime figures (%s: %s)", type(model).__name__, type(err).__name__, err)
        return {"onnx_error": f"{type(err).__name__}: {err}"}
    ms = sorted(t * 1e3 for t in times)  # type: ignore[union-attr]
    med = statistics.median(ms)
    out: dict[str, Any] = {
        "onnx_fps": 1e3 / med if med > 0 else float("inf"), "onnx_latency_ms": med, "onnx_latency_ms_min": ms[0],
        "onnx_max_abs_diff": info["max_abs_diff_all"], "onnx_device": device_name("cpu"),
        "onnxruntime": info["onnxruntime"], "onnx_opset": info["opset"],
    }
    if pytorch_cpu_latency_ms:
        out["onnx_speedup"] = pytorch_cpu_latency_ms / med if med > 0 else None
    log.info("%s: ONNX Runtime %.2f ms (%.2f FPS) on %s, max |diff| %.2g", type(model).__name__, med,
             out["onnx_fps"], out["onnx_device"], out["onnx_max_abs_diff"])
    return out


def dummy_batch(model: nn.Module, *, n_seg: int, has_dvs: bool, resolution: int, n_views: int = 4,
                device: torch.device | str = "cpu", seed: int = 0) -> dict[str, Tensor]:
    """A batch-1 input in the training layout (ARCHITECTURE.md): ``rgb`` (1,V,3,S,S),
    ``dvs`` (1,V,2,S,S) when the dataset has DVS, ``lidar`` (1,L,S,S) with
    ``L = getattr(model, 'lidar_channels', 15)``, and a one-hot ``ls`` (1,C,S,S) (Chen et al.
    reads it as input; other models ignore it)."""
    g = torch.Generator().manual_seed(seed)
    S = resolution
    L = int(getattr(model, "lidar_channels", 15))
    batch = {
        "rgb": torch.rand(1, n_views, 3, S, S, generator=g),
        "lidar": torch.rand(1, L, S, S, generator=g),
        "ls": torch.nn.functional.one_hot(torch.randint(0, n_seg, (1, S, S), generator=g), n_seg)
        .permute(0, 3, 1, 2).float(),
    }
    if has_dvs:
        batch["dvs"] = (torch.rand(1, n_views, 2, S, S, generator=g) > 0.9).float()
    return {k: v.to(device) for k, v in batch.items()}


def measure_model(model: nn.Module, batch: Batch, device: torch.device | str,
                  warmup: int = 10, runs: int = 50) -> dict[str, Any]:
    """All Table III quantities of one model on ``device`` (model moved there)."""
    device = torch.device(device)
    model = model.to(device).eval()
    out: dict[str, Any] = {"params": count_params(model), "size_mb": state_dict_size_mb(model)}
    mem, method = peak_memory_mb(model, batch, device)
    out.update(peak_memory_mb=mem, memory_method=method, is_gpu=device.type == "cuda")
    out.update(measure_fps(model, batch, device, warmup, runs))
    out["threads"] = torch.get_num_threads() if device.type == "cpu" else None
    log.info("%s: %d params, %.3f MB, peak %.1f MB, %.2f FPS (%.2f ms) on %s",
             type(model).__name__, out["params"], out["size_mb"], mem, out["fps"], out["latency_ms"], out["device"])
    return out
