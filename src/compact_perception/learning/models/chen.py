"""Chen et al. latent model baseline for BEVP (Chen, Li, Tomizuka, T-ITS 2021; paper V-D).

Inputs: the front RGB image (`rgb[:, 0]`, view "f") and the top-view LS one-hot image (`ls`,
ground truth, as the paper feeds it).  Structure (BASELINES.md, reference TensorFlow code):

* one encoder per input: conv 5x5/2 (32) -> 3x3/2 (64) -> 3x3/2 (128) -> 3x3/2 (256) ->
  3x3/2 (256) -> valid conv 4x4 (256), LeakyReLU(0.2).  The original is fixed to 128 x 128
  input (4 x 4 left before the valid conv).  To run at other S the geometry adapts without
  changing any weight shape: the r x r map left after the strided convs (r = S/32) is
  zero-padded symmetrically to 4 x 4 when r < 4 (S = 64: the valid 4x4 conv then uses its
  central 2x2 taps) and average-pooled to 1 x 1 after the valid conv when r > 4.  The two
  features are summed (256-d).
* latent (single-frame use of the sequential latent model, documented choice): the first-step
  posterior q(z1 | x) = N(mu, softplus + 1e-5) from Dense 256 -> 256 -> 256 -> 2 x 32, and
  p(z2 | z1) from Dense 32 -> 256 -> 256 -> 2 x 256 (shared by prior and posterior as in the
  reference); p(z1) = N(0, I).  Training samples, eval uses the means.  The decoders read
  [z1, z2] (288-d).
* three decoders: conv-transpose 4x4 valid (256) -> 3x3/2 (256) -> (128) -> (64) -> (32) ->
  5x5/2 (channels), LeakyReLU between; the 4 x 4 map after the first layer is centre-cropped
  (r < 4, the transpose of the encoder's padding) or bilinearly resized (r > 4) to r x r.
  Outputs: RGB reconstruction (sigmoid), LS reconstruction and BEV, each of the last two
  followed by an extra 1x1 conv + sigmoid (the paper's change).

Parameters at S = 128 (the paper's size): 10,928,101 for A/B/C (C = 23, Cb = 9; paper
10,365,211, +5.4 %) and 10,962,403 for nuScenes (paper 10,372,539, +5.7 %).  Because the
size adaptation above changes no weight shape, the counts are the same at every S (for S not a multiple of 32,
e.g. 48, the decoders' last map is resized bilinearly to S).

Loss (returned folded into the single task key, so the dict has exactly `("bevp",)`):
  bevp = BCE + Dice(BEV)  +  [MSE(RGB rec) + BCE(LS rec) + KL(q(z1|x) || N(0, I)) / S^2],
i.e. the BEVP loss plus the negative ELBO normalised per pixel (reconstruction terms are
per-element means, the KL is summed over latent dimensions and divided by the pixel count).
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ...core.catalog import ModelInfo
from .base import DatasetSpec
from .blocks import losses_module

Z1, Z2, FEAT = 32, 256, 256
_ACT_SLOPE = 0.2


K_VALID = 4  # kernel of the valid conv / first transposed conv (4 x 4 left at S = 128)


def _remaining(size: int) -> int:
    """Spatial size left after the five stride-2 'same' convs (S/32, rounded up)."""
    for _ in range(5):
        size = (size + 1) // 2
    return size


def _pad_to(x: Tensor, k: int) -> Tensor:
    """Zero-pad the last two axes symmetrically up to k (no-op when already >= k)."""
    h, w = x.shape[-2:]
    ph, pw = max(k - h, 0), max(k - w, 0)
    return F.pad(x, (pw // 2, pw - pw // 2, ph // 2, ph - ph // 2))


class ChenEncoder(nn.Module):
    """Image -> 256-d feature (5 strided convs + one valid conv)."""

    def __init__(self, in_ch: int) -> None:
        super().__init__()
        self.convs = nn.ModuleList([
            nn.Conv2d(in_ch, 32, 5, stride=2, padding=2),
            nn.Conv2d(32, 64, 3, stride=2, padding=1),
            nn.Conv2d(64, 128, 3, stride=2, padding=1),
            nn.Conv2d(128, 256, 3, stride=2, padding=1),
            nn.Conv2d(256, 256, 3, stride=2, padding=1),
            nn.Conv2d(256, FEAT, K_VALID),
        ])

    def forward(self, x: Tensor) -> Tensor:
        for i, conv in enumerate(self.convs):
            if i == len(self.convs) - 1:
                x = _pad_to(x, K_VALID)
            x = F.leaky_relu(conv(x), _ACT_SLOPE)
        return F.adaptive_avg_pool2d(x, 1).flatten(1)


class ChenDecoder(nn.Module):
    """288-d latent -> (out_ch, S, S) pre-activation map."""

    def __init__(self, out_ch: int) -> None:
        super().__init__()
        self.deconvs = nn.ModuleList([
            nn.ConvTranspose2d(Z1 + Z2, 256, K_VALID),
            nn.ConvTranspose2d(256, 256, 3, stride=2, padding=1, output_padding=1),
            nn.ConvTranspose2d(256, 128, 3, stride=2, padding=1, output_padding=1),
            nn.ConvTranspose2d(128, 64, 3, stride=2, padding=1, output_padding=1),
            nn.ConvTranspose2d(64, 32, 3, stride=2, padding=1, output_padding=1),
            nn.ConvTranspose2d(32, out_ch, 5, stride=2, padding=2, output_padding=1),
        ])

    def forward(self, z: Tensor, size: int) -> Tensor:
        """z (B,288) -> (B,out_ch,size,size)."""
        r = _remaining(size)
        x = z[:, :, None, None]
        for i, deconv in enumerate(self.deconvs):
            x = deconv(x)
            if i == 0 and r < K_VALID:
                o = (K_VALID - r) // 2
                x = x[..., o:o + r, o:o + r]
            elif i == 0 and r > K_VALID:
                x = F.interpolate(x, size=(r, r), mode="bilinear", align_corners=False)
            if i < len(self.deconvs) - 1:
                x = F.leaky_relu(x, _ACT_SLOPE)
        if x.shape[-1] != size:  # S not a multiple of 32 (e.g. 48): resize the last map
            x = F.interpolate(x, size=(size, size), mode="bilinear", align_corners=False)
        return x


def _gaussian_net(in_dim: int, out_dim: int) -> nn.Sequential:
    """Dense 256 -> Dense 256 -> Dense 2 x out_dim (mean, pre-softplus scale)."""
    return nn.Sequential(
        nn.Linear(in_dim, 256), nn.LeakyReLU(_ACT_SLOPE),
        nn.Linear(256, 256), nn.LeakyReLU(_ACT_SLOPE),
        nn.Linear(256, 2 * out_dim),
    )


def _split(params: Tensor) -> tuple[Tensor, Tensor]:
    mu, s = params.chunk(2, dim=1)
    return mu, F.softplus(s) + 1e-5


def _kl_std_normal(mu: Tensor, scale: Tensor) -> Tensor:
    """KL(N(mu, scale^2) || N(0, 1)) summed over latent dims, mean over the batch."""
    kl = 0.5 * (mu.pow(2) + scale.pow(2) - 1.0) - torch.log(scale)
    return kl.sum(dim=1).mean()


class ChenBEV(nn.Module):
    """Front RGB + top-view LS -> latent -> BEV and input reconstructions (task `bevp`)."""

    tasks: tuple[str, ...] = ("bevp",)
    argmax_tasks: tuple[str, ...] = ()  # sigmoid BEV head: eq. (5)'s threshold

    def __init__(self, n_seg: int, n_bev: int) -> None:
        super().__init__()
        self.enc_rgb = ChenEncoder(3)
        self.enc_ls = ChenEncoder(n_seg)
        self.q_z1 = _gaussian_net(FEAT, Z1)
        self.p_z2 = _gaussian_net(Z1, Z2)
        self.dec_rgb = ChenDecoder(3)
        self.dec_ls = ChenDecoder(n_seg)
        self.dec_bev = ChenDecoder(n_bev)
        self.final_ls = nn.Conv2d(n_seg, n_seg, 1)
        self.final_bev = nn.Conv2d(n_bev, n_bev, 1)
        self._aux: dict[str, Tensor] = {}
        self._pixels = 1.0

    def forward(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """`rgb` (B,V,3,S,S) front view + `ls` (B,C,S,S) one-hot -> `bevp` (B,Cb,S,S)."""
        rgb, ls = batch["rgb"][:, 0], batch["ls"]
        size = rgb.shape[-1]
        feat = self.enc_rgb(rgb) + self.enc_ls(ls)
        mu1, sc1 = _split(self.q_z1(feat))
        z1 = mu1 + sc1 * torch.randn_like(mu1) if self.training else mu1
        mu2, sc2 = _split(self.p_z2(z1))
        z2 = mu2 + sc2 * torch.randn_like(mu2) if self.training else mu2
        z = torch.cat([z1, z2], dim=1)
        bev = torch.sigmoid(self.final_bev(self.dec_bev(z, size)))
        # Reconstructions and KL feed the ELBO in compute_losses (kept off the output dict).
        self._aux = {
            "rgb_rec": torch.sigmoid(self.dec_rgb(z, size)),
            "ls_rec": torch.sigmoid(self.final_ls(self.dec_ls(z, size))),
            "kl": _kl_std_normal(mu1, sc1),
        }
        self._pixels = float(size * size)
        return {"bevp": bev}

    def compute_losses(self, outputs: dict[str, Tensor], batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """{"bevp": BCE+Dice(BEV) + negative ELBO per pixel} for the latest forward pass."""
        L = losses_module()
        aux = self._aux
        if not aux:
            raise RuntimeError("compute_losses needs a forward pass first")
        bev = L.bce_dice_loss(outputs["bevp"], batch["bevp"])
        # The reconstructions keep the forward's autocast dtype (bf16/fp16); the training step
        # computes losses outside autocast, so each is cast to its target's dtype (a no-op in an
        # fp32 or fp64 run).
        rec_rgb = F.mse_loss(aux["rgb_rec"].to(batch["rgb"].dtype), batch["rgb"][:, 0])
        rec_ls = F.binary_cross_entropy(aux["ls_rec"].to(batch["ls"].dtype).clamp(1e-6, 1 - 1e-6), batch["ls"])
        kl = aux["kl"].to(bev.dtype) / self._pixels
        return {"bevp": bev + rec_rgb + rec_ls + kl}

    def shared_layers(self) -> dict[str, list[str]]:
        """Single-task model: nothing is shared between tasks."""
        return {}


def build(ds: DatasetSpec, info: ModelInfo) -> ChenBEV:
    """Chen et al.'s BEV network (BEVP)."""
    return ChenBEV(ds.n_seg, ds.n_bev)
