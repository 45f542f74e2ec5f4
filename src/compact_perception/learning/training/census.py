"""The census of a training step: how many aten ops it issues and how often it makes the host
wait for the device.

On a GPU every aten op is (about) one kernel launch, and every read of a device value by the
host (``.item()``, ``float(t)``, ``bool(t)``, ``.tolist()``, a copy to the CPU, an op whose
output size depends on values) stalls the host until the device has drained its queue: a step
that reads a loss every step keeps the GPU idle between launches. :class:`Census` counts both
over a block of code, on any device:

- **ops**: every aten op that reaches the dispatcher below autograd (a
  ``TorchDispatchMode``), the backward's included;
- **syncs**: reads of device values by the host, each with the place in this package's code that
  made it (:attr:`Census.sites`):

  * ``aten::_local_scalar_dense`` (what ``.item()``, ``float()``, ``int()``, ``bool()`` call);
  * a copy from a non-CPU tensor to a CPU one (``_to_copy`` / ``copy_``);
  * ops whose output size depends on the values (``nonzero``, boolean-mask indexing,
    ``masked_select``, ``unique``, ...): CUDA reads the size back before it can allocate;
  * Python-level reads that never reach the dispatcher on a CPU tensor: ``.tolist()``,
    ``.numpy()`` and ``.cpu()`` (a ``TorchFunctionMode``).

On the CPU every tensor is a host tensor, so a CPU census counts a read of any tensor of the run's
device: what would be a device read in a GPU run. Tensors that a GPU run keeps on the host by
PyTorch's design are not counted: the step counters of a non-fused, non-capturable optimiser
(Adam's ``state["step"]``: PyTorch keeps it on the CPU and reads it there), given by
``host_side``. A read is counted once (``.item()`` is one read, not also its
``_local_scalar_dense``).
"""
from __future__ import annotations

import traceback
from collections import Counter
from pathlib import Path
from typing import Any, Callable

import torch
from torch.overrides import TorchFunctionMode
from torch.utils._python_dispatch import TorchDispatchMode

__all__ = ["Census", "optimizer_step_counters", "PYTHON_READS", "SHAPE_SYNC_OPS"]

aten = torch.ops.aten

#: Tensor methods through which Python reads a tensor's values on the host.
PYTHON_READS: frozenset[str] = frozenset({
    "item", "tolist", "numpy", "cpu", "__float__", "__int__", "__bool__", "__index__", "__complex__"})
#: aten ops whose output size (or a Python result) depends on the values: a device read on CUDA.
SHAPE_SYNC_OPS: frozenset[str] = frozenset({
    "_local_scalar_dense", "nonzero", "masked_select", "unique", "_unique", "_unique2", "unique_dim",
    "unique_consecutive", "equal", "is_nonzero", "allclose", "repeat_interleave", "bincount"})

_PACKAGE = str(Path(__file__).resolve().parents[2])


def _site() -> str:
    """The innermost frame of this package (outside this module) that led here: ``file.py:line``."""
    for frame in reversed(traceback.extract_stack()):
        if frame.filename.startswith(_PACKAGE) and not frame.filename.endswith("census.py"):
            return f"{Path(frame.filename).relative_to(_PACKAGE).as_posix()}:{frame.lineno}"
    return "(outside the package)"


def optimizer_step_counters(*objects: Any) -> Callable[[torch.Tensor], bool]:
    """``host_side`` for :class:`Census`: true for the step counter of a non-fused,
    non-capturable optimiser among ``objects`` or their attributes (an optimiser of a loss
    weighting: GradNorm's and UW's own Adam), which PyTorch keeps on the CPU in a GPU run too."""
    found: list[torch.optim.Optimizer] = []
    for obj in objects:
        if isinstance(obj, torch.optim.Optimizer):
            found.append(obj)
        elif hasattr(obj, "__dict__"):
            found.extend(v for v in vars(obj).values() if isinstance(v, torch.optim.Optimizer))

    def host_side(t: torch.Tensor) -> bool:
        if t.dim() != 0:
            return False
        for opt in found:
            on_host = not any(g.get("fused") or g.get("capturable") for g in opt.param_groups)
            if on_host and any(st.get("step") is t for st in opt.state.values()):
                return True
        return False

    return host_side


def _shape_sync(func: Any, args: tuple, kwargs: dict) -> bool:
    name = func._overloadpacket.__name__
    if name == "index" and len(args) > 1:  # boolean-mask indexing: nonzero underneath
        return any(isinstance(i, torch.Tensor) and i.dtype in (torch.bool, torch.uint8) for i in args[1])
    if name == "repeat_interleave":  # the output size is read back unless it is given
        return kwargs.get("output_size") is None
    return name in SHAPE_SYNC_OPS


class _Ops(TorchDispatchMode):
    def __init__(self, census: "Census") -> None:
        super().__init__()
        self.census = census

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        c = self.census
        c.ops += 1
        if c._reading == 0:
            name = func._overloadpacket.__name__
            if _shape_sync(func, args, kwargs) and not (name == "_local_scalar_dense" and c._exempt(args[0])):
                c._count(f"aten::{name}")
            elif func in (aten._to_copy.default, aten.copy_.default):
                src = args[1] if func is aten.copy_.default else args[0]
                if isinstance(src, torch.Tensor) and src.device.type != "cpu":  # (under vmap an arg may be a number)
                    dst_cpu = (args[0].device.type == "cpu" if func is aten.copy_.default
                               else torch.device(kwargs.get("device") or src.device).type == "cpu")
                    if dst_cpu:
                        c._count(f"aten::{name} to the CPU")
        return func(*args, **kwargs)


class _Reads(TorchFunctionMode):
    def __init__(self, census: "Census") -> None:
        super().__init__()
        self.census = census

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        c = self.census
        name = getattr(func, "__name__", "")
        if name in PYTHON_READS and args and isinstance(args[0], torch.Tensor):
            t = args[0]
            if t.device.type == c.device.type and not c._exempt(t):
                c._count(f"Tensor.{name}")
                c._reading += 1
                try:
                    return func(*args, **kwargs)
                finally:
                    c._reading -= 1
        return func(*args, **kwargs)


class Census:
    """Counts aten ops and host reads of ``device``'s tensors over a ``with`` block.

    ``host_side(t)``: tensors a GPU run keeps on the host (:func:`optimizer_step_counters`);
    their reads are not syncs. After the block: :attr:`ops`, :attr:`syncs` and :attr:`sites`
    (a ``Counter`` of ``"what at file.py:line"``)."""

    def __init__(self, device: torch.device | str = "cpu",
                 host_side: Callable[[torch.Tensor], bool] | None = None) -> None:
        self.device = torch.device(device)
        self._host_side = host_side
        self.ops = 0
        self.syncs = 0
        self.sites: Counter[str] = Counter()
        self._reading = 0
        self._modes: list[Any] = []

    def _exempt(self, t: Any) -> bool:
        return isinstance(t, torch.Tensor) and self._host_side is not None and self._host_side(t)

    def _count(self, what: str) -> None:
        self.syncs += 1
        self.sites[f"{what} at {_site()}"] += 1

    def __enter__(self) -> "Census":
        self._modes = [_Reads(self), _Ops(self)]
        for m in self._modes:
            m.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        for m in reversed(self._modes):
            m.__exit__(*exc)
        self._modes = []

    @classmethod
    def of(cls, fn: Callable[[], Any], device: torch.device | str = "cpu",
           host_side: Callable[[torch.Tensor], bool] | None = None) -> tuple["Census", Any]:
        """Run ``fn()`` under a census; returns the census and ``fn``'s result."""
        with cls(device, host_side) as c:
            out = fn()
        return c, out

    def summary(self, limit: int = 8) -> str:
        """``N ops, M syncs`` and the most frequent sync sites."""
        where = "; ".join(f"{n}x {s}" for s, n in self.sites.most_common(limit))
        return f"{self.ops} ops, {self.syncs} syncs" + (f" ({where})" if where else "")
