"""PolarNet baseline for LS (Zhang et al., CVPR 2020; paper section V-D; BASELINES.md).

As in the paper's count (13,403,701; nuScenes 13,404,286 = 23 -> 32 classes, +9 x 65) this is
PolarSeg's ring-connected 2-D U-Net alone, fed with the preprocessed 15-channel LiDAR top view
(no PointNet / compression layer):

  input BN(15) -> double_conv 15->64 -> down 128, 256, 512, 512 (max-pool 2 + double_conv)
  -> up (bilinear x2, concat skip, double_conv) 1024->256, 512->128, 256->64, 128->64
  -> 1x1 conv 64 -> C -> softmax over classes (output `ls`, probabilities).

double_conv = 2 x (ring 3x3 conv -> BN -> LeakyReLU).  Ring connection: before every 3x3 conv
the LAST (angular) axis is padded circularly by 1 and the conv uses padding (1, 0), so features
wrap around 360 degrees.  The original grid is polar (rho, theta); on our Cartesian top view the
ring connection (wrapping the column axis) is kept as an architectural property for fidelity,
not because the grid is periodic.  DropBlock (training-time only, no parameters) is omitted.
Loss (PolarSeg recipe): cross-entropy + Lovasz-softmax, cells with no LiDAR label ignored.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ...core.catalog import ModelInfo
from .base import DatasetSpec
from .blocks import log_probs, losses_module


class RingConv2d(nn.Conv2d):
    """3x3 conv with circular padding along the last axis and zero padding along the other."""

    def __init__(self, in_ch: int, out_ch: int) -> None:
        super().__init__(in_ch, out_ch, kernel_size=3, padding=(1, 0))

    def forward(self, x: Tensor) -> Tensor:
        return super().forward(F.pad(x, (1, 1, 0, 0), mode="circular"))


class DoubleConv(nn.Module):
    """PolarSeg double_conv_circular: 2 x (ring conv -> BN -> LeakyReLU)."""

    def __init__(self, in_ch: int, out_ch: int) -> None:
        super().__init__()
        self.conv1 = RingConv2d(in_ch, out_ch)
        self.bn1 = nn.BatchNorm2d(out_ch)
        self.conv2 = RingConv2d(out_ch, out_ch)
        self.bn2 = nn.BatchNorm2d(out_ch)
        self.act = nn.LeakyReLU(inplace=True)

    def forward(self, x: Tensor) -> Tensor:
        x = self.act(self.bn1(self.conv1(x)))
        return self.act(self.bn2(self.conv2(x)))


class Up(nn.Module):
    """Bilinear x2 upsampling, concatenation with the skip, double_conv."""

    def __init__(self, in_ch: int, out_ch: int) -> None:
        super().__init__()
        self.conv = DoubleConv(in_ch, out_ch)

    def forward(self, x: Tensor, skip: Tensor) -> Tensor:
        x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=True)
        return self.conv(torch.cat([skip, x], dim=1))


class PolarNet(nn.Module):
    """Ring-connected U-Net for LiDAR segmentation (task `ls`)."""

    tasks: tuple[str, ...] = ("ls",)
    argmax_tasks: tuple[str, ...] = ("ls",)  # softmax LS head: scored by its arg-max map (metrics.scored_outputs)
    labelled_maps: tuple[str, ...] = ("ls",)  # its losses' labelled cells, found on the host (data.Labelled)

    def __init__(self, n_classes: int, in_ch: int = 15) -> None:
        super().__init__()
        self.in_ch = self.lidar_channels = in_ch  # the data loader reads `lidar_channels`
        self.input_bn = nn.BatchNorm2d(in_ch)
        self.inc = DoubleConv(in_ch, 64)
        chans = [(64, 128), (128, 256), (256, 512), (512, 512)]
        self.downs = nn.ModuleList(DoubleConv(i, o) for i, o in chans)
        self.ups = nn.ModuleList(Up(i, o) for i, o in [(1024, 256), (512, 128), (256, 64), (128, 64)])
        self.head = nn.Conv2d(64, n_classes, kernel_size=1)

    def forward(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """`lidar` (B,15,S,S) -> `ls` (B,C,S,S) softmax probabilities."""
        x = batch["lidar"]
        if x.shape[1] != self.in_ch:
            raise ValueError(f"PolarNet expects {self.in_ch} LiDAR channels, got {x.shape[1]}")
        feats = [self.inc(self.input_bn(x))]
        for blk in self.downs:
            feats.append(blk(F.max_pool2d(feats[-1], 2)))
        x = feats.pop()
        for blk in self.ups:
            x = blk(x, feats.pop())
        return {"ls": torch.softmax(self.head(x), dim=1)}

    def compute_losses(self, outputs: dict[str, Tensor], batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """Cross-entropy + Lovasz-softmax (PolarSeg), unlabelled (all-zero one-hot) cells ignored."""
        L = losses_module()
        probs, target = outputs["ls"], batch["ls"]
        lab = batch.get("labelled", {}).get("ls")  # where the cells are labelled, if found on the host
        idx, classes = (lab.views[0], lab.classes) if lab is not None else (None, None)
        ce = L.cross_entropy_onehot(log_probs(probs), target, idx)
        return {"ls": ce + L.lovasz_softmax(probs, target, idx, classes)}

    def shared_layers(self) -> dict[str, list[str]]:
        """Single-task model: nothing is shared between tasks."""
        return {}


def build(ds: DatasetSpec, info: ModelInfo) -> PolarNet:
    """PolarNet (LS) on the model's LiDAR channels."""
    return PolarNet(ds.n_seg, in_ch=info.lidar_channels)
