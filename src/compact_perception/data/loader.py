"""PyTorch access to the cache (SPEC 4; docs/ARCHITECTURE.md "Batches").

:class:`CacheDataset` serves compact per-frame tensors straight from the memory-mapped
arrays (uint8 images and class indices, float16 LiDAR and depth); :func:`to_device` moves
a collated batch to the device and only there expands it to float tensors and one-hot
maps (255 = no label -> the all-zero vector), so host memory and host-to-device traffic
stay compact.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, DistributedSampler, RandomSampler, SequentialSampler, default_collate

from ..core.cache import CacheError, read_meta, read_split

log = logging.getLogger(__name__)

#: Keys of a frame served by :class:`CacheDataset` (``dvs`` only when the cache has it).
FRAME_KEYS: tuple[str, ...] = ("rgb", "dvs", "lidar", "de", "ss", "ls", "bevp")


class CacheDataset(Dataset):
    """One split of a cache as a map-style dataset.

    Item ``n`` is a dict of CPU tensors: ``rgb`` uint8 (V,3,S,S), ``dvs`` uint8 (V,2,S,S)
    (if present), ``lidar`` float16 (L,S,S) with L = 15 (eq. (5) layers + 1L) or L = 1
    (channel 14 only, the 1L variant), ``de`` float16 (V,1,S,S), ``ss`` uint8 (V,S,S),
    ``ls`` uint8 (S,S), ``bevp`` uint8 (Cb,S,S), and ``index`` (int64 scalar).
    Arrays are opened lazily in each process (memory maps are not pickled to workers).
    """

    def __init__(self, cache_dir: str | os.PathLike, split: str, lidar_channels: int = 15) -> None:
        if lidar_channels not in (1, 15):
            raise ValueError(f"lidar_channels must be 1 or 15, got {lidar_channels}")
        self.cache_dir = Path(cache_dir)
        self.split = split
        self.lidar_channels = lidar_channels
        self.meta = read_meta(self.cache_dir)
        split_info = read_split(self.cache_dir, split, self.meta)
        self.frame_ids: list[str] = split_info.frame_ids
        self.keys = tuple(k for k in FRAME_KEYS if k in split_info.arrays)
        missing = {"rgb", "lidar", "de", "ss", "ls", "bevp"} - set(self.keys)
        if missing:
            raise CacheError(f"{self.cache_dir / split}: cache lacks {sorted(missing)}")
        n_lidar = split_info.arrays["lidar"].shape[1]
        if lidar_channels == 15 and n_lidar != 15:
            raise CacheError(f"{self.cache_dir / split}: lidar has {n_lidar} channels, 15 requested")
        self._arrays: dict[str, np.ndarray] | None = None

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_arrays"] = None
        return state

    def _open(self) -> dict[str, np.ndarray]:
        if self._arrays is None:
            self._arrays = read_split(self.cache_dir, self.split, self.meta).arrays
        return self._arrays

    def __len__(self) -> int:
        return len(self.frame_ids)

    def __getitem__(self, n: int) -> dict[str, torch.Tensor]:
        arrays = self._open()
        out: dict[str, torch.Tensor] = {}
        for key in self.keys:
            a = arrays[key]
            if key == "lidar" and self.lidar_channels == 1:
                row = np.array(a[n, 14:15])
            else:
                row = np.array(a[n])
            out[key] = torch.from_numpy(row)
        out["index"] = torch.tensor(n, dtype=torch.int64)
        return out


def make_loader(
    cache_dir: str | os.PathLike,
    split: str,
    lidar_channels: int = 15,
    batch_size: int = 6,
    shuffle: bool = False,
    seed: int = 0,
    num_workers: int = 0,
    drop_last: bool = False,
    distributed: bool = False,
    pin_memory: bool = False,
    labelled: Sequence[str] = (),
) -> DataLoader:
    """A DataLoader over :class:`CacheDataset` with deterministic order.

    Shuffling draws from a ``torch.Generator`` seeded with ``seed`` (same seed -> same
    sequence of epochs). With ``distributed`` a ``DistributedSampler(seed=seed)`` shards the
    split over ranks (call ``loader.sampler.set_epoch(epoch)`` each epoch). Worker processes
    stay alive between epochs (``persistent_workers``) when ``num_workers > 0``.

    The loader never draws from the global torch RNG (it has a generator of its own for the
    workers' base seed), so the global RNG that dropout uses follows the same sequence for
    any ``num_workers`` and after a resume: worker counts cannot change a result.

    ``labelled``: class maps whose labelled pixels the loader finds for the losses
    (:class:`Labelled`, under ``"labelled"``; a model's ``labelled_maps``).
    """
    ds = CacheDataset(cache_dir, split, lidar_channels)
    if distributed:
        sampler: Any = DistributedSampler(ds, shuffle=shuffle, seed=seed, drop_last=drop_last)
    elif shuffle:
        sampler = RandomSampler(ds, generator=torch.Generator().manual_seed(seed))
    else:
        sampler = SequentialSampler(ds)
    return DataLoader(
        ds,
        batch_size=batch_size,
        sampler=sampler,
        num_workers=num_workers,
        drop_last=drop_last,
        persistent_workers=num_workers > 0,
        pin_memory=pin_memory,
        generator=torch.Generator().manual_seed(seed),
        collate_fn=LabelledCollate(labelled) if labelled else None,
    )


def set_epoch(loader: DataLoader, epoch: int, seed: int) -> None:
    """Fix the shuffling order of ``epoch`` (seed + epoch): the same on every run and after a
    resume, without rebuilding the loader and its worker processes."""
    sampler = loader.sampler
    if isinstance(sampler, DistributedSampler):
        sampler.set_epoch(epoch)
    elif isinstance(sampler, RandomSampler) and sampler.generator is not None:
        sampler.generator.manual_seed(seed + epoch)


def one_hot(index: torch.Tensor, num_classes: int, dim: int, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Expand a uint8 class-index tensor into a one-hot tensor along new axis ``dim``; 255 -> all zeros."""
    idx = index.long()
    valid = idx != 255
    idx = torch.where(valid, idx, torch.zeros_like(idx))
    shape = list(idx.shape)
    shape.insert(dim, num_classes)
    out = torch.zeros(shape, dtype=dtype, device=idx.device)
    out.scatter_(dim, idx.unsqueeze(dim), valid.unsqueeze(dim).to(dtype))
    return out


@dataclass(frozen=True)
class Labelled:
    """Where a class map (``ss``, ``ls``) has labels, found on the host from the batch's uint8
    class indices (255 = no label) while the loader collates it, so a loss that leaves unlabelled
    pixels out (cross entropy, Lovasz-softmax: the baselines') need not read the device to find
    them. A model asks for it with ``labelled_maps`` (:func:`make_loader`'s ``labelled``).

    ``views``: per view, the flat indices (over the view's (B, S, S) pixels, row-major) of its
    labelled pixels, int64; their number is ``numel()``, known on the host.
    ``classes``: the classes labelled somewhere in the batch, ascending."""

    views: tuple[torch.Tensor, ...]
    classes: tuple[int, ...]

    def to(self, device: torch.device, non_blocking: bool = False) -> "Labelled":
        return Labelled(tuple(v.to(device, non_blocking=non_blocking) for v in self.views), self.classes)

    def pin_memory(self) -> "Labelled":
        """The views in page-locked memory (a DataLoader with ``pin_memory=True`` calls it on a batch's
        custom types), so their ``non_blocking`` copy to a GPU does not stall the stream."""
        return Labelled(tuple(v.pin_memory() for v in self.views), self.classes)


def labelled_pixels(index: torch.Tensor) -> Labelled:
    """:class:`Labelled` of a uint8 class-index map on the host, (B,V,S,S) or (B,S,S) (one view)."""
    per_view = [index[:, v] for v in range(index.shape[1])] if index.dim() == 4 else [index]
    views = tuple(torch.nonzero(m.reshape(-1) != 255).reshape(-1) for m in per_view)
    return Labelled(views, tuple(int(c) for c in torch.unique(index[index != 255]).tolist()))


class LabelledCollate:
    """The loader's collate: the default one, plus ``"labelled"``: ``{key: Labelled}`` for the
    class maps ``keys`` (picklable, for worker processes)."""

    def __init__(self, keys: Sequence[str]) -> None:
        self.keys = tuple(keys)

    def __call__(self, frames: list[dict[str, torch.Tensor]]) -> dict[str, Any]:
        batch: dict[str, Any] = default_collate(frames)
        batch["labelled"] = {k: labelled_pixels(batch[k]) for k in self.keys if k in batch}
        return batch


def to_device(
    batch: dict[str, Any], device: torch.device | str, num_seg_classes: int, dtype: torch.dtype = torch.float32
) -> dict[str, Any]:
    """Move a collated batch to ``device`` and expand it there (docs/ARCHITECTURE.md "Batches").

    Returns float tensors: ``rgb`` (B,V,3,S,S) = uint8/255, ``dvs`` (B,V,2,S,S), ``lidar``
    (B,L,S,S), ``de`` (B,V,1,S,S), ``ss`` (B,V,C,S,S) one-hot, ``ls`` (B,C,S,S) one-hot
    (zero vector where no point), ``bevp`` (B,Cb,S,S); ``index`` stays int64; a loader's
    ``"labelled"`` (:class:`Labelled` per class map) moves too.
    """
    dev = torch.device(device)
    nb = dev.type == "cuda"
    out: dict[str, torch.Tensor] = {}
    for key, t in batch.items():
        if key == "labelled":
            out[key] = {k: lab.to(dev, non_blocking=nb) for k, lab in t.items()}
            continue
        if not isinstance(t, torch.Tensor):
            continue
        t = t.to(dev, non_blocking=nb)
        if key == "rgb":
            out[key] = t.to(dtype) / 255.0
        elif key == "ss":
            out[key] = one_hot(t, num_seg_classes, dim=2, dtype=dtype)
        elif key == "ls":
            out[key] = one_hot(t, num_seg_classes, dim=1, dtype=dtype)
        elif key == "index":
            out[key] = t
        else:
            out[key] = t.to(dtype)
    return out
