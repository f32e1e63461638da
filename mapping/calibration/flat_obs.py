"""Labelled voxel observations in flat (CSR) form, the input of 3D calibration fitting, GLFS
training and map evaluation: every observation of every labelled voxel of one or more
observation caches (``mapping.calibration.obs_cache``), concatenated.

Fusion over them is ``mapping.fusion.fuse_flat`` (index_add over the voxel axis), so the cost
follows the number of observations, not the busiest voxel.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np
import torch

from calnav.mapping.calibration.obs_cache import ObsCache


def csr_select(offsets: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(counts (len(ids),), flat observation indices) of the CSR rows ``ids`` under ``offsets``."""
    counts = offsets[ids + 1] - offsets[ids]
    starts = np.repeat(offsets[ids], counts)
    return counts, starts + (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts))


@dataclass
class FlatObservations:
    """logits (n, K) float32; voxel (n,) int64 index of each observation's voxel, sorted;
    distance_m (n,) metres; angle_deg (n,) degrees; weight (n,) per-observation weight given
    while mapping (ones if none); labels (N,) int64 ground-truth class per voxel (>= 0, or the void
    label for void voxels when built with ``keep_void``)."""

    logits: torch.Tensor
    voxel: torch.Tensor
    distance_m: torch.Tensor
    angle_deg: torch.Tensor
    weight: torch.Tensor
    labels: torch.Tensor

    @property
    def num_voxels(self) -> int:
        return int(self.labels.shape[0])

    @property
    def num_classes(self) -> int:
        return int(self.logits.shape[1])

    def __len__(self) -> int:
        return int(self.logits.shape[0])

    @classmethod
    def from_caches(cls, caches: Iterable[ObsCache], max_voxels: int | None = None, seed: int = 0,
                    ignore_index: int = -1, keep_void: bool = False) -> "FlatObservations":
        """All labelled voxels (label != ``ignore_index``) of ``caches`` (each must have labels,
        see ``ObsCache.label_from_mesh``); with ``max_voxels``, a seeded uniform subset of them.
        ``keep_void``: void voxels too, labelled ``ignore_index`` (for metrics that score the
        predictions on void, e.g. the authors' mIoU; never for training)."""
        parts, k = [], None
        for i, cache in enumerate(caches):
            if cache.labels is None:
                raise ValueError(f"observation cache {i} has no ground-truth labels; call label_from_mesh first")
            if k is not None and cache.num_classes != k:
                raise ValueError(f"caches disagree on the number of classes ({k} vs {cache.num_classes})")
            k = cache.num_classes
            csr = cache._require()
            labels = cache.labels
            keep = np.arange(len(labels)) if keep_void else np.flatnonzero(labels != ignore_index)
            off = csr["offsets"]
            keep = keep[off[keep + 1] > off[keep]]
            counts, obs = csr_select(off, keep)
            parts.append(dict(
                logits=csr["logits"][obs], counts=counts, labels=labels[keep],
                distance=csr["distance"][obs], angle=csr["angle"][obs],
                weight=csr["weight"][obs] if "weight" in csr else np.ones(len(obs), np.float32)))
        if not parts or sum(int((p["labels"] != ignore_index).sum()) for p in parts) == 0:
            raise ValueError("no labelled voxel observations: the caches are empty or every voxel is void")
        cat = {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}
        flat = cls._build(cat, k, ignore_index if keep_void else None)
        if max_voxels is not None and flat.num_voxels > max_voxels:
            ids = np.sort(np.random.default_rng(seed).choice(flat.num_voxels, max_voxels, replace=False))
            flat = flat.subset(ids)
        return flat

    @classmethod
    def _build(cls, cat: dict[str, np.ndarray], k: int, void: int | None = None) -> "FlatObservations":
        voxel = np.repeat(np.arange(len(cat["counts"])), cat["counts"])
        t = lambda a, dt: torch.from_numpy(np.ascontiguousarray(a)).to(dt)  # noqa: E731
        logits = t(cat["logits"], torch.float32)
        if not bool(torch.isfinite(logits).all()):
            raise ValueError("observation logits contain NaN or inf")
        labels = t(cat["labels"], torch.int64)
        real = labels[labels != void] if void is not None else labels
        if len(real) and (int(real.min()) < 0 or int(real.max()) >= k):
            raise ValueError(f"voxel labels must be class ids in [0, {k}) (void excluded)")
        return cls(logits, t(voxel, torch.int64), t(cat["distance"], torch.float32), t(cat["angle"], torch.float32),
                   t(cat["weight"], torch.float32), labels)

    def offsets(self) -> np.ndarray:
        """(N + 1,) start of each voxel's observations."""
        counts = np.bincount(self.voxel.numpy(), minlength=self.num_voxels)
        return np.concatenate([[0], np.cumsum(counts)])

    def subset(self, voxel_ids: Sequence[int] | np.ndarray) -> "FlatObservations":
        """The voxels ``voxel_ids`` (renumbered 0..len-1 in the given order) and their observations."""
        ids = np.asarray(voxel_ids, dtype=np.int64)
        counts, obs = csr_select(self.offsets(), ids)
        obs = torch.from_numpy(obs)
        voxel = torch.from_numpy(np.repeat(np.arange(len(ids)), counts))
        return FlatObservations(self.logits[obs], voxel, self.distance_m[obs], self.angle_deg[obs],
                                self.weight[obs], self.labels[torch.from_numpy(ids)])

    def batches(self, batch_voxels: int, rng: np.random.Generator) -> Iterable["FlatObservations"]:
        """Shuffled voxel mini-batches covering every voxel once."""
        order = rng.permutation(self.num_voxels)
        for s in range(0, len(order), batch_voxels):
            yield self.subset(np.sort(order[s:s + batch_voxels]))

    def class_frequency(self) -> np.ndarray:
        """(K,) fraction of voxels per ground-truth class."""
        return np.bincount(self.labels.numpy(), minlength=self.num_classes) / max(self.num_voxels, 1)
