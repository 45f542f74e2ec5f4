"""The view axis of a task's tensors, which losses and metrics both read (docs/ARCHITECTURE.md):
per-view tasks are (B, V, C, H, W), single-view tasks (B, C, H, W), treated as V = 1."""
from __future__ import annotations

from torch import Tensor

__all__ = ["as_views", "class_dim"]


def as_views(x: Tensor) -> Tensor:
    """(B,C,H,W) -> (B,1,C,H,W); (B,V,C,H,W) unchanged."""
    if x.dim() == 4:
        return x.unsqueeze(1)
    if x.dim() == 5:
        return x
    raise ValueError(f"expected a (B,C,H,W) or (B,V,C,H,W) tensor, got shape {tuple(x.shape)}")


def class_dim(x: Tensor) -> int:
    """Channel (class) axis: 1 for (B,C,H,W), 2 for (B,V,C,H,W)."""
    if x.dim() == 4:
        return 1
    if x.dim() == 5:
        return 2
    raise ValueError(f"expected a (B,C,H,W) or (B,V,C,H,W) tensor, got shape {tuple(x.shape)}")
