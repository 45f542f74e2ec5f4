"""Device-generic batch-1 inference timing for the GPU benchmark path (issue 15).

:func:`build_inference` turns a model and a batch-1 input into a callable for one of the
variants the benchmark compares -- precision (``fp32``, ``bf16``, ``fp16`` autocast),
channels-last, ``torch.compile`` and CUDA graphs -- and :func:`benchmark_variants` times
each with :func:`compact_perception.evaluation.efficiency.measure_fps` (warm-up excluded, the
device synchronised around every timed call, median latency) and checks its outputs against
float32 eager.

The same code runs on a CPU: CUDA graphs are CUDA-only and are then skipped (the result says
so), reduced precision runs through CPU autocast (emulated on CPUs without native bf16).

CUDA graphs: the model is run three times on a side stream (warm-up, as the CUDA-graph
documentation requires before capture), then one forward is captured into a
``torch.cuda.CUDAGraph`` with static input tensors; a timed call copies the batch into the
static inputs and replays the graph (outputs are the graph's static outputs).

Batch normalisation folded into the convolutions (:func:`fold_batchnorm`, variants with
``fold_bn``): at inference a BatchNorm2d is a per-channel affine map of its running statistics,
so one that reads a convolution's output and nothing else is merged into that convolution's
weights and bias, one kernel fewer per pair. The folded network equals the unfolded one within
:data:`FOLD_TOLERANCE` (float32 rounding of the merged weights), checked on the variant's batch.
"""
from __future__ import annotations

import copy
import logging
from dataclasses import asdict, dataclass
from typing import Any, Callable, Mapping

import torch
from torch import Tensor, nn

from ..learning.training.precision import autocast_context, batch_to_channels_last, maybe_compile, to_channels_last
from .efficiency import device_name, measure_fps, synchronize

log = logging.getLogger(__name__)

__all__ = ["EXACT_TOLERANCE", "FOLD_TOLERANCE", "Variant", "benchmark_variants", "build_inference", "default_variants",
           "fastest_exact", "fold_batchnorm", "max_abs_diff", "table3_inference", "table3_variants"]

#: The largest absolute output difference a folded network may show against the unfolded one in
#: float32 (the project's networks end in sigmoids, softmaxes and a depth map in [0, 1]; measured
#: on the compact network: about 1e-6).
FOLD_TOLERANCE = 1e-4

#: A variant is *exact* when its outputs differ from float32 eager's by at most this: float32
#: rounding of a reordered computation (CUDA graphs replay the same kernels; folded batch norms
#: round their merged weights), not a reduced precision (bf16 / fp16 move outputs by ~1e-3 to 1e-2).
EXACT_TOLERANCE = FOLD_TOLERANCE

_WEIGHT_DTYPES = {"bf16": torch.bfloat16, "fp16": torch.float16}


@dataclass(frozen=True)
class Variant:
    """One way of running inference: precision, memory format, compiler, CUDA graph."""

    name: str
    precision: str = "fp32"
    channels_last: bool = False
    compile: bool = False
    cuda_graph: bool = False
    fold_bn: bool = False
    weights: str = "fp32"   # "bf16" / "fp16": the network and its inputs cast to that type (no autocast)


def default_variants(device: torch.device | str) -> list[Variant]:
    """The variants the GPU benchmark compares: float32 eager, bf16 and fp16 autocast (bf16 only
    where the device runs it), channels-last + the fastest precision, and on CUDA a CUDA graph of
    float32 and of the reduced precision, each with batch normalisation folded into the convolutions
    too. On a CPU: fp32, bf16, channels-last, both (a caller may add ``fold_bn`` variants)."""
    dev = torch.device(device)
    if dev.type == "cuda":
        low = ["fp16"] + (["bf16"] if torch.cuda.is_bf16_supported(including_emulation=False) else [])
        best = "bf16" if "bf16" in low else "fp16"
        out = [Variant("fp32")] + [Variant(p, precision=p) for p in low]
        out += [Variant(f"{best}+channels_last", best, channels_last=True),
                Variant("fp32+cuda_graph", cuda_graph=True),
                Variant(f"{best}+cuda_graph", best, cuda_graph=True),
                Variant(f"{best}+channels_last+cuda_graph", best, channels_last=True, cuda_graph=True),
                Variant("fp32+fold_bn", fold_bn=True),
                Variant("fp32+fold_bn+cuda_graph", cuda_graph=True, fold_bn=True),
                Variant(f"{best}+fold_bn+channels_last+cuda_graph", best, channels_last=True, cuda_graph=True,
                        fold_bn=True)]
        return out
    return [Variant("fp32"), Variant("bf16", "bf16"), Variant("channels_last", channels_last=True),
            Variant("bf16+channels_last", "bf16", channels_last=True)]


def table3_variants(device: torch.device | str) -> list[Variant]:
    """The variants the benchmark stage times for Table III at the hardware's pace: float32 eager
    (the reference, Table III's own column), the exact candidates (CUDA graphs, folded batch norms,
    channels-last) and the network cast to bf16 / fp16 (weights and inputs cast once, no autocast
    per call), reported but not exact. CUDA graphs only on CUDA; bf16 only where the device has it."""
    dev = torch.device(device)
    cuda = dev.type == "cuda"
    graphs = [False, True] if cuda else [False]
    out = [Variant("fp32")]
    for g in graphs:
        tag = "+cuda_graph" if g else ""
        if g:
            out.append(Variant("fp32+cuda_graph", cuda_graph=True))
        out += [Variant(f"fp32+fold_bn{tag}", fold_bn=True, cuda_graph=g),
                Variant(f"fp32+fold_bn+channels_last{tag}", fold_bn=True, channels_last=True, cuda_graph=g)]
    low = ["fp16"] if cuda else []
    if not cuda or torch.cuda.is_bf16_supported(including_emulation=False):
        low.append("bf16")
    for w in low:
        out += [Variant(f"{w}_weights+fold_bn{'+cuda_graph' if g else ''}", fold_bn=True, cuda_graph=g, weights=w)
                for g in graphs]
    return out


def fastest_exact(results: list[dict[str, Any]], tolerance: float = EXACT_TOLERANCE) -> dict[str, Any] | None:
    """The fastest timed result of :func:`benchmark_variants` whose outputs are within
    ``tolerance`` of float32 eager's (:data:`EXACT_TOLERANCE`); ``None`` when none was timed."""
    exact = [r for r in results if "fps" in r and r.get("max_abs_diff", float("inf")) <= tolerance]
    return max(exact, key=lambda r: r["fps"], default=None)


def table3_inference(model: nn.Module, batch: Mapping[str, Tensor], device: torch.device | str,
                     warmup: int, runs: int) -> dict[str, Any]:
    """Table III at the hardware's pace (the benchmark stage, on CUDA): every
    :func:`table3_variants` variant timed, the fastest exact one, and float32 eager beside it."""
    results = benchmark_variants(model, batch, device, table3_variants(device), warmup, runs)
    keep = ("name", "fps", "latency_ms", "max_abs_diff", "speedup", "cuda_graph", "bn_folded", "error")
    best = fastest_exact(results)
    eager = next((r for r in results if r["name"] == "fp32" and "fps" in r), None)
    return {
        "exact_tolerance": EXACT_TOLERANCE,
        "eager_fp32": {k: eager[k] for k in keep if k in eager} if eager else None,
        "fastest_exact": {k: best[k] for k in keep if k in best} if best else None,
        "variants": [{k: r[k] for k in keep if k in r} for r in results],
    }


def _outputs(out: Any) -> dict[str, Tensor]:
    if isinstance(out, Mapping):
        return {k: v for k, v in out.items() if isinstance(v, Tensor)}
    if isinstance(out, Tensor):
        return {"out": out}
    return {str(i): v for i, v in enumerate(out) if isinstance(v, Tensor)}


def max_abs_diff(a: Any, b: Any) -> float:
    """Largest ``|a - b|`` over the tensors both outputs share (compared in float32)."""
    oa, ob = _outputs(a), _outputs(b)
    diffs = [float((oa[k].float() - ob[k].float()).abs().max()) for k in oa if k in ob and oa[k].numel()]
    return max(diffs) if diffs else 0.0


def _conv_bn_pairs(model: nn.Module, batch: Mapping[str, Tensor]) -> list[tuple[nn.Conv2d, nn.BatchNorm2d]]:
    """The (convolution, batch norm) pairs of ``model`` where, in a forward of ``batch``, the batch
    norm reads the convolution's output and no other module does (forward hooks; an op outside a
    module that also reads it is caught by :func:`fold_batchnorm`'s check)."""
    made: dict[int, tuple[nn.Module, Tensor]] = {}   # id(output) -> (conv, output kept alive)
    readers: dict[int, set[int]] = {}                 # id(conv) -> ids of the modules reading its outputs
    sources: dict[int, set[int]] = {}                 # id(bn) -> ids of the convs (or 0) it read from
    modules = {id(m): m for m in model.modules()}

    def conv_out(mod: nn.Module, _inp: Any, out: Any) -> None:
        if isinstance(out, Tensor):
            made[id(out)] = (mod, out)

    def reads(mod: nn.Module, inp: tuple) -> None:
        for t in inp:
            if isinstance(t, Tensor) and id(t) in made:
                readers.setdefault(id(made[id(t)][0]), set()).add(id(mod))
        if isinstance(mod, nn.BatchNorm2d):
            t = inp[0] if inp else None
            sources.setdefault(id(mod), set()).add(id(made[id(t)][0]) if id(t) in made else 0)

    hooks = [m.register_forward_pre_hook(reads) for m in model.modules() if not list(m.children())]
    hooks += [m.register_forward_hook(conv_out) for m in model.modules() if isinstance(m, nn.Conv2d)]
    try:
        with torch.no_grad():
            model(dict(batch))
    finally:
        for h in hooks:
            h.remove()
    pairs = []
    for bn_id, convs in sources.items():
        conv_id = next(iter(convs))
        bn = modules[bn_id]
        if len(convs) == 1 and conv_id and readers.get(conv_id) == {bn_id} and bn.running_mean is not None:
            pairs.append((modules[conv_id], bn))
    return pairs


def _merge(conv: nn.Conv2d, bn: nn.BatchNorm2d) -> None:
    """``conv``'s weight and bias with ``bn`` (eval mode: running statistics) applied, in float64."""
    w = conv.weight.detach().double()
    b = conv.bias.detach().double() if conv.bias is not None else torch.zeros(w.shape[0], dtype=torch.float64,
                                                                                device=w.device)
    gamma = bn.weight.detach().double() if bn.weight is not None else torch.ones_like(b)
    beta = bn.bias.detach().double() if bn.bias is not None else torch.zeros_like(b)
    scale = gamma / torch.sqrt(bn.running_var.double() + bn.eps)
    conv.weight = nn.Parameter((w * scale.reshape(-1, 1, 1, 1)).to(conv.weight.dtype))
    conv.bias = nn.Parameter(((b - bn.running_mean.double()) * scale + beta).to(conv.weight.dtype))


def fold_batchnorm(model: nn.Module, batch: Mapping[str, Tensor],
                   tolerance: float = FOLD_TOLERANCE) -> tuple[nn.Module, int]:
    """An inference copy of ``model`` (eval mode; ``model`` is left as it is) with every batch
    normalisation that reads a convolution's output, and is its only reader, merged into that
    convolution (``W' = W g / sqrt(var + eps)``, ``b' = (b - mean) g / sqrt(var + eps) + beta``,
    per output channel, computed in float64) and replaced by an identity; returns the copy and the
    number of pairs folded. ``ValueError`` when its outputs on ``batch`` differ from ``model``'s by
    more than ``tolerance``."""
    model = model.eval()
    folded = copy.deepcopy(model)
    pairs = _conv_bn_pairs(folded, batch)
    parents = {id(child): (parent, name) for parent in folded.modules() for name, child in parent.named_children()}
    for conv, bn in pairs:
        _merge(conv, bn)
        parent, name = parents[id(bn)]
        setattr(parent, name, nn.Identity())
    with torch.no_grad():
        diff = max_abs_diff(folded(dict(batch)), model(dict(batch)))
    if not diff <= tolerance:
        raise ValueError(f"batch norm folded into {len(pairs)} convolutions changes the outputs by {diff:.3g} "
                         f"(more than {tolerance:g})")
    return folded, len(pairs)


def _cuda_graph_fn(fn: Callable[[Any], Any], batch: Mapping[str, Tensor], device: torch.device,
                   warmup: int = 3) -> Callable[[Mapping[str, Tensor]], Any]:
    """Capture ``fn(batch)`` into a CUDA graph (module doc); returns the replaying callable."""
    static = {k: v.clone() for k, v in batch.items()}
    stream = torch.cuda.Stream(device)
    stream.wait_stream(torch.cuda.current_stream(device))
    with torch.cuda.stream(stream), torch.inference_mode():
        for _ in range(warmup):
            fn(static)
    torch.cuda.current_stream(device).wait_stream(stream)
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph), torch.inference_mode():
        static_out = fn(static)

    def replay(b: Mapping[str, Tensor]) -> Any:
        for k, v in b.items():
            if k in static and v.data_ptr() != static[k].data_ptr():
                static[k].copy_(v)
        graph.replay()
        return static_out

    return replay


def build_inference(model: nn.Module, batch: Mapping[str, Tensor], device: torch.device | str,
                    variant: Variant) -> tuple[Callable[[Mapping[str, Tensor]], Any], dict[str, Any], dict[str, Tensor]]:
    """``(fn, info, batch)`` for ``variant``: ``fn(batch)`` runs one inference forward of ``model``
    (moved to ``device``, eval mode) under the variant's autocast, memory format, compiler and
    CUDA graph, with batch normalisation folded into the convolutions for a ``fold_bn`` variant
    (a copy: ``model`` keeps its own); ``info`` records what actually ran (``cuda_graph`` False on a
    CPU, ``compiled`` False after a compiler fallback, ``bn_folded`` the pairs folded); ``batch``
    is the input in the variant's memory format."""
    dev = torch.device(device)
    model = model.to(dev).eval()
    folded = 0
    if variant.fold_bn:  # on the network's own layout, before any change of memory format
        model, folded = fold_batchnorm(model.to(memory_format=torch.contiguous_format),
                                       {k: v.to(dev) for k, v in batch.items()})
    if variant.weights != "fp32":  # the network and its floating inputs in the reduced type, once
        low = _WEIGHT_DTYPES[variant.weights]
        model = (copy.deepcopy(model) if not variant.fold_bn else model).to(dtype=low)
        batch = {k: v.to(low) if v.is_floating_point() else v for k, v in batch.items()}
    if variant.channels_last:
        model = to_channels_last(model)
        batch = batch_to_channels_last(batch)
    else:
        model = model.to(memory_format=torch.contiguous_format)
    batch = {k: v.to(dev) for k, v in batch.items()}
    fwd = maybe_compile(model, variant.compile)

    def run(b: Mapping[str, Tensor]) -> Any:
        with autocast_context(dev, variant.precision):
            return fwd(b)

    info: dict[str, Any] = asdict(variant)
    info["cuda_graph"] = bool(variant.cuda_graph and dev.type == "cuda")
    if variant.cuda_graph and dev.type != "cuda":
        info["note"] = "CUDA graphs need a CUDA device: eager"
    if info["cuda_graph"]:
        fn: Callable[[Mapping[str, Tensor]], Any] = _cuda_graph_fn(run, batch, dev)
    else:
        fn = run
    info["compiled"] = bool(variant.compile and getattr(fwd, "compiled", False))
    if variant.fold_bn:
        info["bn_folded"] = folded
    return fn, info, batch


def benchmark_variants(model: nn.Module, batch: Mapping[str, Tensor], device: torch.device | str,
                       variants: list[Variant], warmup: int = 10, runs: int = 50) -> list[dict[str, Any]]:
    """Time every variant at batch 1 on ``device`` (:func:`measure_fps`) and compare its outputs
    with float32 eager (``max_abs_diff``); adds ``speedup`` = fp32-eager latency / latency.
    A variant that fails (e.g. bf16 on a GPU without it) is reported with ``error``."""
    dev = torch.device(device)
    model = model.to(dev).eval()
    with torch.inference_mode():
        ref = {k: v.float().clone() for k, v in _outputs(model({k: v.to(dev) for k, v in batch.items()})).items()}
    results: list[dict[str, Any]] = []
    base_ms: float | None = None
    for v in variants:
        try:
            fn, info, vb = build_inference(model, batch, dev, v)
            with torch.inference_mode():
                out = fn(vb)
                synchronize(dev)
                info["max_abs_diff"] = max_abs_diff(out, ref)
            info.update(measure_fps(fn, vb, dev, warmup, runs))
        except Exception as err:  # noqa: BLE001 - one variant's failure is a reported result
            log.warning("variant %s failed: %s", v.name, err)
            info = {**asdict(v), "error": f"{type(err).__name__}: {err}", "device": device_name(dev)}
        if v.name == "fp32" and "latency_ms" in info:
            base_ms = info["latency_ms"]
        results.append(info)
    model.to(memory_format=torch.contiguous_format)
    for r in results:
        if base_ms is not None and "latency_ms" in r:
            r["speedup"] = base_ms / r["latency_ms"]
    return results
