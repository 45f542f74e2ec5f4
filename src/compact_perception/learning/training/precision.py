"""The training and inference fast path (issue 15): mixed precision, channels-last, torch.compile.

Drop-in pieces for the training loop (``train.precision``, ``train.channels_last``,
``train.compile``); each rule is stated on its function.

- :func:`resolve_precision` turns ``fp32 | bf16 | fp16 | auto`` into the precision a run uses.
- :func:`autocast_context` is the forward's autocast (a no-op for ``fp32``).
- :func:`make_grad_scaler` is a ``torch.amp.GradScaler`` that is enabled for ``fp16`` only; a
  disabled scaler passes ``scale``/``unscale_``/``step``/``update`` straight through, so the
  float32 loop is unchanged.
- :func:`float_outputs` casts a model's outputs to float32 so the losses (logs of
  probabilities, sums over ~10^5 elements) are computed in float32 outside autocast.
- :func:`to_channels_last` / :func:`batch_to_channels_last`: NHWC memory format for the model's
  4-D weights and the batch (per-view NHWC for the (B, V, C, H, W) tensors).
- :func:`maybe_compile` wraps a model's forward in ``torch.compile`` and falls back to eager,
  with one warning, where the compiler toolchain is missing or compilation fails.

Under ``fp32`` every function is the identity (or a disabled no-op context / scaler), so a
float32 run gives bit-identical results with or without these calls.
"""
from __future__ import annotations

import functools
import logging
import platform
import subprocess
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any, Callable, Literal, Mapping

import torch
from torch import Tensor, nn

log = logging.getLogger(__name__)

Precision = Literal["fp32", "bf16", "fp16"]
#: Values of ``train.precision``.
PRECISION_CHOICES: tuple[str, ...] = ("fp32", "bf16", "fp16", "auto")
#: Autocast dtype of each reduced precision.
AUTOCAST_DTYPES: dict[str, torch.dtype] = {"bf16": torch.bfloat16, "fp16": torch.float16}
#: x86 / Arm CPU flags that mean bfloat16 matrix arithmetic in hardware (AMX tiles, AVX-512 BF16
#: dot products, Armv8.6 BF16); without one of them a CPU emulates bf16 and autocast is slower.
CPU_BF16_FLAGS: frozenset[str] = frozenset({"amx_bf16", "avx512_bf16", "bf16"})

__all__ = [
    "AUTOCAST_DTYPES", "CPU_BF16_FLAGS", "PRECISION_CHOICES", "CompiledForward", "Precision",
    "autocast_context", "batch_to_channels_last", "cpu_flags", "cpu_has_native_bf16", "float_outputs",
    "make_grad_scaler", "maybe_compile", "resolve_precision", "to_channels_last",
]


# ----------------------------------------------------------------------------- hardware
@functools.lru_cache(maxsize=1)
def cpu_flags() -> frozenset[str]:
    """The CPU's feature flags (``flags`` on x86, ``Features`` on Arm) from ``/proc/cpuinfo``,
    lower case; empty where the file does not exist (macOS, Windows) or cannot be read."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        text = ""
    if not text and platform.system() == "Darwin":  # Apple silicon: hw.optional.arm.FEAT_BF16
        try:
            out = subprocess.run(["sysctl", "-n", "hw.optional.arm.FEAT_BF16"], capture_output=True,
                                 text=True, timeout=5, check=False).stdout.strip()
            return frozenset({"bf16"}) if out == "1" else frozenset()
        except (OSError, subprocess.SubprocessError):
            return frozenset()
    flags: set[str] = set()
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip().lower() in ("flags", "features"):
            flags.update(value.lower().split())
    return frozenset(flags)


def cpu_has_native_bf16() -> bool:
    """True when the CPU runs bfloat16 matrix products in hardware: one of
    :data:`CPU_BF16_FLAGS` (``amx_bf16``, ``avx512_bf16``, Arm ``bf16``) is present.
    ``torch.backends.cpu.get_cpu_capability()`` names only the vector ISA ATen was dispatched
    to (``AVX2``, ``AVX512``, ...), not bf16 support, so it is logged, not used."""
    return bool(cpu_flags() & CPU_BF16_FLAGS)


def _cuda_capability(device: torch.device) -> tuple[int, int]:
    return torch.cuda.get_device_capability(device)


def resolve_precision(name: str, device: torch.device | str) -> Precision:
    """The precision a run uses, from ``train.precision`` and the device.

    Rules:

    - ``fp32`` -> ``fp32`` everywhere.
    - ``auto`` picks the fastest precision the hardware runs natively, never one slower than
      float32, and is deterministic (a hardware rule, not a timing race):

      * CUDA: ``bf16`` on compute capability >= 8.0 with native bf16
        (``torch.cuda.is_bf16_supported(including_emulation=False)``: Ampere and later);
        ``fp16`` on 7.x (Volta/Turing tensor cores); ``fp32`` below 7.0 (Pascal and older
        run fp16 matrix products at a fraction of the fp32 rate or no faster).
      * CPU: ``bf16`` where :func:`cpu_has_native_bf16` (AMX-BF16, AVX-512-BF16, Arm BF16),
        else ``fp32`` (an AVX2-only CPU emulates bf16: slower than float32).
      * any other device: ``fp32``.
    - ``bf16`` explicit: CUDA without bf16 support raises ``ValueError``; a CPU without native
      bf16 runs it emulated (correct, slower) after a warning.
    - ``fp16`` explicit: CUDA as asked (with the gradient scaler of :func:`make_grad_scaler`);
      a CPU runs it emulated (slower, also scaled) after a warning.

    Unknown names raise ``ValueError`` naming the ``train.precision`` param.
    """
    if name not in PRECISION_CHOICES:
        raise ValueError(f"train.precision: {name!r} is not one of {list(PRECISION_CHOICES)}")
    device = torch.device(device)
    if name == "fp32":
        return "fp32"
    if device.type == "cuda":
        major, _minor = _cuda_capability(device)
        bf16_ok = torch.cuda.is_bf16_supported(including_emulation=False)
        if name == "auto":
            if major >= 8 and bf16_ok:
                return "bf16"
            return "fp16" if major >= 7 else "fp32"
        if name == "bf16" and not bf16_ok:
            raise ValueError(f"train.precision: 'bf16' but {torch.cuda.get_device_name(device)} "
                             f"(compute capability {major}.x) has no native bfloat16; use 'fp16' or 'auto'")
        return name  # type: ignore[return-value]
    if device.type == "cpu":
        native = cpu_has_native_bf16()
        if name == "auto":
            choice: Precision = "bf16" if native else "fp32"
            log.info("train.precision auto on CPU (%s, native bf16: %s) -> %s",
                     torch.backends.cpu.get_cpu_capability(), native, choice)
            return choice
        if name == "bf16" and not native:
            log.warning("train.precision 'bf16': this CPU has no native bfloat16 (%s); autocast is "
                        "emulated and slower than float32", torch.backends.cpu.get_cpu_capability())
        if name == "fp16":
            log.warning("train.precision 'fp16' on a CPU: float16 autocast is emulated and slower than "
                        "float32; 'bf16' or 'fp32' suit a CPU")
        return name  # type: ignore[return-value]
    return "fp32" if name == "auto" else name  # type: ignore[return-value]


# ----------------------------------------------------------------------------- autocast / scaler
def autocast_context(device: torch.device | str, precision: str, cache: bool = True) -> AbstractContextManager[Any]:
    """``torch.autocast(device.type, dtype)`` for ``bf16`` / ``fp16``; ``nullcontext()`` for
    ``fp32`` (so float32 runs execute exactly the code they ran before). Wrap the model's
    forward only; compute the losses outside, on :func:`float_outputs`. ``cache=False``: no cache
    of the weights' low-precision casts (the same values, cast again at each use), as a step
    captured in a CUDA graph needs."""
    if precision == "fp32":
        return nullcontext()
    if precision not in AUTOCAST_DTYPES:
        raise ValueError(f"precision {precision!r} is not one of fp32, bf16, fp16 (resolve 'auto' first)")
    return torch.autocast(torch.device(device).type, dtype=AUTOCAST_DTYPES[precision], cache_enabled=cache)


def make_grad_scaler(device: torch.device | str, precision: str) -> torch.amp.GradScaler:
    """A ``torch.amp.GradScaler`` enabled only for ``fp16`` (float16's small exponent range makes
    small gradients underflow without loss scaling; bfloat16 has float32's range and needs none).
    Disabled, ``scale(x)`` returns ``x``, ``unscale_`` and ``update`` do nothing and ``step(opt)``
    is ``opt.step()``: call it unconditionally."""
    dev = torch.device(device)
    return torch.amp.GradScaler(dev.type, enabled=precision == "fp16")


def float_outputs(outputs: Mapping[str, Any]) -> dict[str, Any]:
    """The model's outputs with every floating tensor in float32 (float64 stays float64;
    float32 tensors are returned as they are, so an fp32 run is unchanged)."""
    out: dict[str, Any] = {}
    for k, v in outputs.items():
        if isinstance(v, Tensor) and v.is_floating_point() and v.dtype in (torch.float16, torch.bfloat16):
            out[k] = v.float()
        else:
            out[k] = v
    return out


# ----------------------------------------------------------------------------- memory format
def to_channels_last(model: nn.Module) -> nn.Module:
    """The model with every 4-D parameter and buffer in ``torch.channels_last`` (NHWC) layout,
    in place (``model.to(memory_format=...)``); values are unchanged, only strides."""
    return model.to(memory_format=torch.channels_last)


def tensor_to_channels_last(t: Tensor) -> Tensor:
    """NHWC strides for a 4-D (N, C, H, W) tensor; for a 5-D (B, V, C, H, W) multi-view tensor the
    strides of a (B, V, H, W, C) array, so that every view ``t[:, v]`` is a channels-last 4-D
    tensor (what the compact model's per-view convolutions see). Other tensors are returned as
    they are. Values never change."""
    if t.dim() == 4 and t.is_floating_point():
        return t.contiguous(memory_format=torch.channels_last)
    if t.dim() == 5 and t.is_floating_point():
        return t.permute(0, 1, 3, 4, 2).contiguous().permute(0, 1, 4, 2, 3)
    return t


#: The network's inputs in a batch (the other maps are its targets).
INPUT_KEYS: tuple[str, ...] = ("rgb", "dvs", "lidar")


def batch_to_channels_last(batch: Mapping[str, Any], inputs_only: bool = False) -> dict[str, Any]:
    """:func:`tensor_to_channels_last` on every tensor of a dict batch (inputs and targets), or on
    its inputs only (:data:`INPUT_KEYS`)."""
    return {k: tensor_to_channels_last(v) if isinstance(v, Tensor) and (not inputs_only or k in INPUT_KEYS) else v
            for k, v in batch.items()}


# ----------------------------------------------------------------------------- torch.compile
def _is_compile_failure(err: BaseException) -> bool:
    """An error of the compiler stack (TorchDynamo, Inductor, the C++ toolchain it calls), not of
    the model: those raise again in eager mode and are not swallowed."""
    if isinstance(err, (OSError, subprocess.SubprocessError, ImportError)):
        return True
    mod = type(err).__module__ or ""
    return mod.startswith(("torch._dynamo", "torch._inductor", "torch._functorch", "torch.fx"))


class CompiledForward:
    """A ``torch.compile``-d forward of ``eager`` that falls back to ``eager`` for good, with one
    warning, the first time compilation fails (missing C++ compiler, missing Python headers,
    an unsupported op). Not an ``nn.Module``: keep using ``eager`` for ``state_dict``,
    ``train()``/``eval()``, ``compute_losses`` and the loss weighting's shared layers; it shares
    the parameters, so both see the same weights."""

    def __init__(self, eager: nn.Module, compiled: Callable[..., Any] | None, reason: str = "") -> None:
        self.eager = eager
        self._compiled = compiled
        self.fallback_reason = reason

    @property
    def compiled(self) -> bool:
        """Whether calls still go through the compiled forward."""
        return self._compiled is not None

    def _fall_back(self, reason: str) -> None:
        self._compiled = None
        self.fallback_reason = reason
        _warn_fallback(reason)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        if self._compiled is not None:
            try:
                return self._compiled(*args, **kwargs)
            except Exception as err:  # noqa: BLE001 - filtered just below
                if not _is_compile_failure(err):
                    raise
                self._fall_back(f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}")
        return self.eager(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:  # tasks, lidar_channels, compute_losses, ...
        if name in ("eager", "_compiled", "fallback_reason"):
            raise AttributeError(name)
        return getattr(self.eager, name)


_warned: set[str] = set()


def _warn_fallback(reason: str) -> None:
    """One warning per process (``logging`` and ``warnings``), however many models fall back."""
    if "compile" in _warned:
        log.debug("torch.compile unavailable (%s); eager mode", reason)
        return
    _warned.add("compile")
    import warnings

    msg = f"torch.compile is unavailable here ({reason}); running the eager model"
    log.warning(msg)
    warnings.warn(msg, RuntimeWarning, stacklevel=3)


def maybe_compile(model: nn.Module, enabled: bool, **compile_kwargs: Any) -> nn.Module | CompiledForward:
    """``model`` itself when ``enabled`` is false; else a :class:`CompiledForward` around
    ``torch.compile(model, **compile_kwargs)``.

    Compilation is lazy (it happens at the first call), so a failure is caught either when
    ``torch.compile`` raises or at the first call that compiles (also a recompilation, e.g. on
    the switch to eval mode); then one warning is emitted per process and the eager model runs
    from then on. Errors of the model itself propagate (they come back from the eager call).
    """
    if not enabled:
        return model
    try:
        compiled = torch.compile(model, **compile_kwargs)
    except Exception as err:  # noqa: BLE001 - any failure to set up the compiler means eager
        fwd = CompiledForward(model, None)
        fwd._fall_back(f"{type(err).__name__}: {err}")
        return fwd
    return CompiledForward(model, compiled)
