"""Shared building blocks (paper section III-A, Fig. 2).

`ConvBlock` is the paper's "common convolution block": 2 x (3x3 convolution + batch
normalisation + ReLU).  Pooling (2x2 max) and upsampling (2x bilinear) are applied by the
caller, so a block never changes the spatial size.
"""
from __future__ import annotations

import importlib
from types import ModuleType

import torch
import torch.nn.functional as F
from torch import Tensor, nn

#: Bias value used with Kaiming-normal weights (the authors' initialisation, section IV-D).
INIT_BIAS: float = 0.01


def kaiming_init_(module: nn.Module, bias: float = INIT_BIAS) -> None:
    """Kaiming-normal (fan-in, ReLU) weights and a constant bias for every conv in `module`."""
    for m in module.modules():
        if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d)):
            nn.init.kaiming_normal_(m.weight, nonlinearity="relu")
            if m.bias is not None:
                nn.init.constant_(m.bias, bias)


class ConvBlock(nn.Module):
    """2 x (3x3 conv (with bias) + BN + ReLU), `in_ch -> out_ch -> out_ch` (section III-A).

    Parameters: 9*in*out + out (conv1) + 2*out (bn1) + 9*out*out + out (conv2) + 2*out (bn2).
    """

    def __init__(self, in_ch: int, out_ch: int, dropout: float = 0.0) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(in_ch, out_ch, kernel_size=3, padding=1)
        self.bn1 = nn.BatchNorm2d(out_ch)
        self.conv2 = nn.Conv2d(out_ch, out_ch, kernel_size=3, padding=1)
        self.bn2 = nn.BatchNorm2d(out_ch)
        self.act = nn.ReLU(inplace=True)
        self.drop = nn.Dropout(dropout) if dropout > 0 else nn.Identity()

    def forward(self, x: Tensor) -> Tensor:
        x = self.act(self.bn1(self.conv1(x)))
        x = self.act(self.bn2(self.conv2(x)))
        return self.drop(x)


def down(x: Tensor) -> Tensor:
    """2x2 max pooling, stride 2 (encoder path)."""
    return F.max_pool2d(x, kernel_size=2, stride=2)


def up(x: Tensor, size: tuple[int, int] | None = None) -> Tensor:
    """2x bilinear upsampling (decoder path); `size` overrides the factor for odd sizes."""
    if size is None:
        return F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=True)
    return F.interpolate(x, size=size, mode="bilinear", align_corners=True)


def count_parameters(model: nn.Module) -> int:
    """Weights, biases and BN affine parameters (what the paper's Table IV counts)."""
    return sum(p.numel() for p in model.parameters())


def losses_module() -> ModuleType:
    """`compact_perception.learning.losses`, imported lazily so the models import without it."""
    return importlib.import_module("compact_perception.learning.losses")


def log_probs(probs: Tensor, eps: float = 1e-7) -> Tensor:
    """Log of softmax probabilities, usable as logits: log_softmax(log p) == log p."""
    return torch.log(probs.clamp_min(eps))
