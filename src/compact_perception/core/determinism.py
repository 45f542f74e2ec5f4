"""The same bytes on any x86-64 machine (AVX2-only or AVX-512/AMX): pinned numeric back-ends.

Numeric libraries pick their kernels from the CPU they find, and the kernels round
differently: numpy's AVX-512 code paths (SVML transcendental functions) differ from its
AVX2/libm ones in the last bits, OpenBLAS picks a matrix kernel per core type (Haswell,
Zen, SkylakeX, ...), PyTorch's ATen and oneDNN kernels differ between AVX2 and AVX-512,
and every threaded reduction depends on the thread count. A different last bit in a
ray-cast depth or a projected LiDAR point moves a pixel, and a different rounding in a
convolution's gradient grows over an epoch, so the machine would decide a result.

:func:`pin_numeric_libraries` removes the machine from the result by fixing each library
to the same instruction-set ceiling, AVX2 with FMA, which every x86-64 machine this
project targets has. It sets environment variables that the libraries read when they
load (numpy, OpenBLAS) or at their first operation (ATen, oneDNN), so it runs before numpy
is imported: :mod:`pipeline` (the stage package) calls it first thing, and child processes
inherit it. The values replace what the environment says, since the environment is part of
the machine. :func:`set_threads` fixes PyTorch's intra-op thread count from params
(``train.num_threads``), so a 16-core machine computes like a 2-core one.

A machine without AVX2 cannot honour the ceiling and may produce other bytes; it is
outside what the project promises.
"""
from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import torch

#: numpy 1.26's dispatchable AVX-512 targets (``numpy.core._multiarray_umath.__cpu_dispatch__``).
NUMPY_AVX512 = ("AVX512F", "AVX512CD", "AVX512_KNL", "AVX512_KNM", "AVX512_SKX", "AVX512_CLX",
                "AVX512_CNL", "AVX512_ICL")

#: Environment that fixes every numeric back-end to AVX2 kernels and single-threaded BLAS.
PINNED_ENV: dict[str, str] = {
    "NPY_DISABLE_CPU_FEATURES": " ".join(NUMPY_AVX512),  # numpy: no AVX-512 loops (SVML)
    "OPENBLAS_CORETYPE": "Haswell",                      # OpenBLAS: the AVX2+FMA kernels
    "OPENBLAS_NUM_THREADS": "1",                         # OpenBLAS: no threaded splits
    "ATEN_CPU_CAPABILITY": "avx2",                       # PyTorch ATen kernels
    "ONEDNN_MAX_CPU_ISA": "AVX2",                        # oneDNN convolutions
    "DNNL_MAX_CPU_ISA": "AVX2",                          # oneDNN's older name of the same
    "MKL_CBWR": "COMPATIBLE",                            # MKL: vendor-independent results
}


#: Set to 1 to leave the machine's own kernels in place (the cross-machine test's control,
#: or a speed comparison); results may then differ between machines.
UNPINNED_ENV_VAR = "COMPACT_PERCEPTION_UNPINNED"


def pin_numeric_libraries() -> None:
    """Set :data:`PINNED_ENV` in this process (and so in its children).

    Must run before numpy is imported; PyTorch reads its two variables at its first
    operation, so importing torch earlier is harmless as long as no tensor op ran.
    """
    if os.environ.get(UNPINNED_ENV_VAR) == "1":
        return
    os.environ.update(PINNED_ENV)


#: The pins PyTorch reads (at its first operation); :func:`release_torch_pins` lifts them.
TORCH_PINS = ("ATEN_CPU_CAPABILITY", "ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA")


def release_torch_pins() -> None:
    """Let PyTorch use the CPU's own kernels (bf16/AMX for mixed precision): only effective
    before its first tensor operation, and results then depend on the machine."""
    for key in TORCH_PINS:
        os.environ.pop(key, None)


def pin_opencv() -> None:
    """Turn off OpenCV's run-time dispatched SIMD (AVX2/AVX-512) so its results do not
    depend on the CPU; the baseline code path is the same everywhere."""
    import cv2

    if os.environ.get(UNPINNED_ENV_VAR) != "1":
        cv2.setUseOptimized(False)


def set_threads(n: int) -> None:
    """Fix PyTorch's intra-op threads (a threaded reduction's result depends on the count)."""
    import torch

    if os.environ.get(UNPINNED_ENV_VAR) != "1":
        torch.set_num_threads(int(n))


#: cuBLAS's workspace settings under which its GEMMs are deterministic (CUDA 10.2 and later).
CUBLAS_DETERMINISTIC = (":4096:8", ":16:8")


def apply_policy(device: "torch.device", train: Any) -> None:
    """The one determinism and precision policy of every stage that runs a network (training,
    evaluation, the benchmark stage, the benchmarks' scripts), before the stage's first kernel:
    ``train.tf32`` and cuDNN's settings everywhere (they act on a GPU only; without them a GPU runs
    float32 convolutions in TF32, PyTorch's default for cuDNN), and on a CUDA device
    :func:`set_determinism` whole. On a CPU ``torch.use_deterministic_algorithms`` is left as it
    is outside training: every CPU kernel used is deterministic already, and the flag's filling of
    uninitialised memory would cost a CPU forward about 9% (Table III's CPU timings and the
    evaluate stage would move) for no change of any output."""
    import torch

    if device.type == "cuda":
        set_determinism(device, bool(train.deterministic), bool(train.tf32))
        return
    torch.backends.cuda.matmul.allow_tf32 = bool(train.tf32)
    torch.backends.cudnn.allow_tf32 = bool(train.tf32)
    torch.backends.cudnn.deterministic = bool(train.deterministic)
    torch.backends.cudnn.benchmark = not train.deterministic


def set_determinism(device: "torch.device", deterministic: bool, tf32: bool) -> None:
    """The determinism policy of every stage that runs a network (``train.deterministic``,
    ``train.tf32``; docs/gpu.md; :func:`apply_policy`).

    - ``tf32`` false (the default): float32 matrix products and convolutions on a GPU run in full
      float32, not TF32 (PyTorch's default for cuDNN on Ampere and later); no effect on a CPU.
    - ``deterministic`` true (the default): every op that has a deterministic kernel uses it
      (``torch.use_deterministic_algorithms``), cuDNN picks deterministic algorithms and does not
      benchmark, and on CUDA ``CUBLAS_WORKSPACE_CONFIG`` is set (before the first cuBLAS call of
      the process, which this precedes) so cuBLAS's GEMMs are repeatable. The ops PyTorch has no
      deterministic CUDA kernel for (the bilinear upsampling's and max-unpooling's backward, which
      every network here uses) still run, with PyTorch's warning: a CUDA run is then repeatable
      up to their atomic-add order, not bit for bit. On a CPU every kernel used is deterministic.
    - ``deterministic`` false: cuDNN benchmarks and picks its fastest algorithms (a GPU run's bytes
      then vary between runs).
    """
    import torch

    if device.type == "cuda" and deterministic and os.environ.get("CUBLAS_WORKSPACE_CONFIG") not in CUBLAS_DETERMINISTIC:
        os.environ["CUBLAS_WORKSPACE_CONFIG"] = CUBLAS_DETERMINISTIC[0]
    torch.backends.cuda.matmul.allow_tf32 = bool(tf32)
    torch.backends.cudnn.allow_tf32 = bool(tf32)
    torch.backends.cudnn.deterministic = bool(deterministic)
    torch.backends.cudnn.benchmark = not deterministic
    torch.use_deterministic_algorithms(bool(deterministic), warn_only=True)


def resolve_device(pref: str) -> "torch.device":
    """``train.device``: ``cuda`` (an error without one), ``cpu``, or ``auto`` (CUDA when present)."""
    import torch

    if pref == "cuda" or (pref == "auto" and torch.cuda.is_available()):
        if not torch.cuda.is_available():
            raise RuntimeError("train.device is 'cuda' but no CUDA device is available")
        return torch.device("cuda")
    return torch.device("cpu")
