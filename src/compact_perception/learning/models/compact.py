"""The compact multi-task perception model (paper section III-A, Fig. 2; SPEC 5).

Layout (reproduces Table IV exactly; channels c = (16, 32, 64, 128), 3 pooling levels, so the
bottlenecks run at S/8; every "block" is a `ConvBlock` = 2 x (3x3 conv + bias, BN, ReLU)):

* Encoders (RGB, DVS over V = 4 views; LiDAR over 1 top view), `MultiViewEncoder`:
  per-view level-0 block in->16 and level-1 block 16->32 (each view its own weights, as Fig. 2's
  caption says), then ONE fusion block per modality over the concatenated views,
  V*32 -> 64 at S/4 (dropout 0.5), max-pooled to S/8.
* `bottleneck1`: block (n_modalities*64) -> 128 (3 modalities; 2 without DVS), dropout 0.5.
* Decoders DE / SS / LS, `MultiViewDecoder`: ONE centre block 128 -> 64 at S/4 (dropout 0.5)
  shared by the views of a task, then per view: level-1 block (64+32) -> 32 with the level-1
  skip, level-0 block (32+16) -> 16 with the level-0 skip, 1x1 head 16 -> out (+bias).
  Skips: RGB -> SS, DVS -> DE, LiDAR -> LS; without DVS (nuScenes) DE takes the RGB skips.
  Heads: ReLU for DE (1 channel), sigmoid for SS / LS (C classes).
* Second encoders over the outputs: DE (4 views, in 1), SS (4 views, in C), LS (1 view, in C),
  same `MultiViewEncoder` layout; `bottleneck2`: block 3*64 -> 128 (dropout 0.5).
* BEVP decoder: `MultiViewDecoder` with one view, skips from the LS second encoder, sigmoid
  head 16 -> Cb.

Arithmetic (block(i, o) = 9io + 9o^2 + 6o, head(i, o) = io + o), simulated 1L (C = 23, Cb = 9):
enc_rgb 178,368 + enc_dvs 177,792 + enc_lidar 72,240 + bottleneck1 369,408 + dec_de 296,516 +
dec_ss 298,012 + dec_ls 157,735 + enc_de 177,216 + enc_ss 189,888 + enc_ls 75,408 +
bottleneck2 369,408 + dec_bevp 157,497 = 2,519,488.  15L adds 14*16*9 = 2,016 (first LiDAR
conv) = 2,521,504.  nuScenes (C = Cb = 32, no DVS) = 2,519,488 - 177,792 (DVS encoder)
- 73,728 (bottleneck1 input 192 -> 128) + 4*9*17 + 9*17 (SS/LS heads) + 4*9*9*16 + 9*9*16
(first SS/LS second-encoder convs) + 23*17 (BEVP head) = 2,275,604 (1L), 2,277,620 (15L).
All four are asserted in tests/test_models.py.  Note the per-view weights (Fig. 2's "each view
has its own encoder") stop at S/2; the S/4 fusion blocks, the bottlenecks and the decoder
centre blocks are shared across views -- the only layout that gives the published counts.

Inputs: `rgb` (B,V,3,S,S), `dvs` (B,V,2,S,S) when the dataset has DVS, `lidar` (B,L,S,S);
a 1-layer model given the 15-channel tensor reads channel 14 (the flattened image, eq. 2-5).
S must be divisible by 8 (16 in the pipeline).
"""
from __future__ import annotations

from typing import Sequence

import torch
from torch import Tensor, nn

from ...core.catalog import ModelInfo
from .base import DatasetSpec
from .blocks import ConvBlock, down, kaiming_init_, losses_module, up

CH: tuple[int, int, int, int] = (16, 32, 64, 128)


class MultiViewEncoder(nn.Module):
    """Per-view blocks at S and S/2, then one fusion block over all views at S/4 (Fig. 2)."""

    def __init__(self, in_ch: int, n_views: int, dropout: float = 0.5) -> None:
        super().__init__()
        self.level0 = nn.ModuleList(ConvBlock(in_ch, CH[0]) for _ in range(n_views))
        self.level1 = nn.ModuleList(ConvBlock(CH[0], CH[1]) for _ in range(n_views))
        self.fuse = ConvBlock(n_views * CH[1], CH[2], dropout=dropout)

    def forward(self, x: Tensor) -> tuple[list[Tensor], list[Tensor], Tensor]:
        """x: (B,V,C,S,S) -> (level-0 skips, level-1 skips, fused features at S/8)."""
        s0 = [blk(x[:, v]) for v, blk in enumerate(self.level0)]
        s1 = [blk(down(f)) for f, blk in zip(s0, self.level1)]
        fused = self.fuse(torch.cat([down(f) for f in s1], dim=1))
        return s0, s1, down(fused)


class MultiViewDecoder(nn.Module):
    """Shared centre block at S/4, per-view skip blocks at S/2 and S, 1x1 heads (Fig. 2)."""

    def __init__(self, out_ch: int, n_views: int, dropout: float = 0.5) -> None:
        super().__init__()
        self.centre = ConvBlock(CH[3], CH[2], dropout=dropout)
        self.level1 = nn.ModuleList(ConvBlock(CH[2] + CH[1], CH[1]) for _ in range(n_views))
        self.level0 = nn.ModuleList(ConvBlock(CH[1] + CH[0], CH[0]) for _ in range(n_views))
        self.heads = nn.ModuleList(nn.Conv2d(CH[0], out_ch, kernel_size=1) for _ in range(n_views))

    def forward(self, z: Tensor, s0: list[Tensor], s1: list[Tensor]) -> Tensor:
        """z: bottleneck output at S/8 -> (B,V,out,S,S) pre-activation maps."""
        c = up(self.centre(up(z)), s1[0].shape[-2:])  # S/8 -> S/4 (centre) -> S/2
        outs = []
        for v in range(len(self.heads)):
            x = self.level1[v](torch.cat([c, s1[v]], dim=1))
            x = self.level0[v](torch.cat([up(x, s0[v].shape[-2:]), s0[v]], dim=1))
            outs.append(self.heads[v](x))
        return torch.stack(outs, dim=1)


class CompactPerception(nn.Module):
    """Compact MTL model performing DE, SS, LS and BEVP in one pass (section III-A)."""

    tasks: tuple[str, ...] = ("de", "ss", "ls", "bevp")
    argmax_tasks: tuple[str, ...] = ()  # sigmoid heads: eq. (5)'s threshold

    def __init__(
        self,
        n_seg: int,
        n_bev: int,
        lidar_channels: int,
        has_dvs: bool = True,
        n_views: int = 4,
        dropout: float = 0.5,
        tasks: Sequence[str] = ("de", "ss", "ls", "bevp"),
    ) -> None:
        """``tasks`` (default all four) builds a single- or few-task network of the same layout
        (the study's single-task references): the decoders of the tasks asked for, and for BEVP
        the whole second stage, which reads the DE, SS and LS outputs."""
        super().__init__()
        unknown = [t for t in tasks if t not in type(self).tasks]
        if unknown or not tasks:
            raise ValueError(f"tasks {list(tasks)}: expected a non-empty subset of {list(type(self).tasks)}")
        self.tasks = tuple(t for t in type(self).tasks if t in tasks)  # canonical order
        first_stage = set(self.tasks) | ({"de", "ss", "ls"} if "bevp" in self.tasks else set())
        self.n_seg, self.n_bev, self.n_views = n_seg, n_bev, n_views
        self.lidar_channels, self.has_dvs = lidar_channels, has_dvs
        self.enc_rgb = MultiViewEncoder(3, n_views, dropout)
        self.enc_dvs = MultiViewEncoder(2, n_views, dropout) if has_dvs else None
        self.enc_lidar = MultiViewEncoder(lidar_channels, 1, dropout)
        n_mod = 3 if has_dvs else 2
        self.bottleneck1 = ConvBlock(n_mod * CH[2], CH[3], dropout=dropout)
        self.dec_de = MultiViewDecoder(1, n_views, dropout) if "de" in first_stage else None
        self.dec_ss = MultiViewDecoder(n_seg, n_views, dropout) if "ss" in first_stage else None
        self.dec_ls = MultiViewDecoder(n_seg, 1, dropout) if "ls" in first_stage else None
        self.enc_de = self.enc_ss = self.enc_ls = self.bottleneck2 = self.dec_bevp = None
        if "bevp" in self.tasks:
            self.enc_de = MultiViewEncoder(1, n_views, dropout)
            self.enc_ss = MultiViewEncoder(n_seg, n_views, dropout)
            self.enc_ls = MultiViewEncoder(n_seg, 1, dropout)
            self.bottleneck2 = ConvBlock(3 * CH[2], CH[3], dropout=dropout)
            self.dec_bevp = MultiViewDecoder(n_bev, 1, dropout)
        kaiming_init_(self)

    def _lidar(self, lidar: Tensor) -> Tensor:
        if lidar.shape[1] == self.lidar_channels:
            return lidar
        if self.lidar_channels == 1 and lidar.shape[1] == 15:
            return lidar[:, 14:15]  # channel 14 = the 1-layer image (SPEC 4)
        raise ValueError(f"lidar has {lidar.shape[1]} channels, model expects {self.lidar_channels}")

    def forward(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """Predictions `de` (B,V,1,S,S) ReLU, `ss` (B,V,C,S,S), `ls` (B,C,S,S), `bevp` (B,Cb,S,S)."""
        r0, r1, rz = self.enc_rgb(batch["rgb"])
        l0, l1, lz = self.enc_lidar(self._lidar(batch["lidar"]).unsqueeze(1))
        feats = [rz]
        if self.enc_dvs is not None:
            d0, d1, dz = self.enc_dvs(batch["dvs"])
            feats.append(dz)
        else:
            d0, d1 = r0, r1  # nuScenes: DE decoders take the RGB skips (section IV-B)
        feats.append(lz)
        z1 = self.bottleneck1(torch.cat(feats, dim=1))
        out: dict[str, Tensor] = {}
        if self.dec_de is not None:
            out["de"] = torch.relu(self.dec_de(z1, d0, d1))
        if self.dec_ss is not None:
            out["ss"] = torch.sigmoid(self.dec_ss(z1, r0, r1))
        if self.dec_ls is not None:
            ls = torch.sigmoid(self.dec_ls(z1, l0, l1))  # (B,1,C,S,S)
            out["ls"] = ls[:, 0]
        if self.dec_bevp is not None:
            _, _, ez = self.enc_de(out["de"])
            _, _, sz = self.enc_ss(out["ss"])
            t0, t1, tz = self.enc_ls(ls)
            z2 = self.bottleneck2(torch.cat([ez, sz, tz], dim=1))
            out["bevp"] = torch.sigmoid(self.dec_bevp(z2, t0, t1))[:, 0]
        return {t: out[t] for t in self.tasks}

    def compute_losses(self, outputs: dict[str, Tensor], batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """Section III-B: Huber (delta 0.5, eq. 1-2) for DE, BCE + Dice (eq. 3) for SS/LS/BEVP."""
        L = losses_module()
        loss = {
            "de": lambda: L.huber_loss(outputs["de"], batch["de"], delta=0.5),
            "ss": lambda: L.bce_dice_loss(outputs["ss"], batch["ss"]),
            "ls": lambda: L.bce_dice_loss(outputs["ls"], batch["ls"]),
            "bevp": lambda: L.bce_dice_loss(outputs["bevp"], batch["bevp"]),
        }
        return {t: loss[t]() for t in self.tasks}

    def shared_layers(self) -> dict[str, list[str]]:
        """MGN's W(s) (eq. 6): first conv of bottleneck 1 (DE/SS/LS) and of bottleneck 2 (BEVP)."""
        w1, w2 = ["bottleneck1.conv1"], ["bottleneck2.conv1"]
        return {t: list(w2 if t == "bevp" else w1) for t in self.tasks}


def build(ds: DatasetSpec, info: ModelInfo, tasks: Sequence[str] | None = None) -> CompactPerception:
    """The compact network of section III-A for a dataset (1 or 15 LiDAR channels, DVS or not);
    ``tasks`` builds it for a subset of its tasks (default all)."""
    return CompactPerception(ds.n_seg, ds.n_bev, lidar_channels=info.lidar_channels, has_dvs=ds.has_dvs,
                             n_views=ds.n_views, tasks=tuple(tasks or info.tasks))
