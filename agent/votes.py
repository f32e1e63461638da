"""The fused map's 2D projection, incrementally: each observed voxel's latest vote (cell,
arg-max class, confidence) and the per-(class, cell) sums and counts it feeds (a cell's class
confidence is the mean of the votes for that class there, paper Sec. VI-C).

``VoxelVotes.vote`` replaces the votes of the voxels a frame fused into and moves the sums by the
difference, in one compiled pass (numba): the sorted merge of the new votes, the subtraction
of the replaced ones and the addition of the new ones per (class, cell) bin -- summed in
float64 in the order numpy's ``bincount`` would (replaced votes first, then new ones, each in
key order) and applied in float32, so the maps are the numpy version's bit for bit
(tests/agent/test_mapping.py keeps that version as the reference).
"""
from __future__ import annotations

import numpy as np

from calnav.common.jit import compiled


class VoxelVotes:
    """Each observed voxel's latest vote: sorted int64 voxel keys with (flat cell, class,
    confidence)."""

    KEY_BITS = 21                      # bits per voxel axis in a key: +-2^20 voxels (+-52 km at 5 cm)
    KEY_OFFSET = 1 << (KEY_BITS - 1)

    def __init__(self) -> None:
        self.keys = np.zeros(0, np.int64)
        self.cells = np.zeros(0, np.int64)
        self.classes = np.zeros(0, np.int16)
        self.conf = np.zeros(0, np.float32)
        self._slot = np.zeros(0, np.int32)   # per (class, cell): scratch of a vote, zero between votes

    @classmethod
    def encode(cls, ijk: np.ndarray) -> np.ndarray:
        """(N, 3) int voxel indices -> (N,) int64 keys."""
        v = ijk.astype(np.int64) + cls.KEY_OFFSET
        return (v[:, 0] << (2 * cls.KEY_BITS)) | (v[:, 1] << cls.KEY_BITS) | v[:, 2]

    @classmethod
    def decode(cls, keys: np.ndarray) -> np.ndarray:
        """(N,) int64 keys -> (N, 3) int64 voxel indices (``encode``'s inverse)."""
        mask = (1 << cls.KEY_BITS) - 1
        return np.stack([(keys >> (2 * cls.KEY_BITS)) - cls.KEY_OFFSET, ((keys >> cls.KEY_BITS) & mask) - cls.KEY_OFFSET,
                         (keys & mask) - cls.KEY_OFFSET], axis=1)

    def vote(self, keys: np.ndarray, ijk: np.ndarray, classes: np.ndarray, conf: np.ndarray, voxel_m: float,
             origin: np.ndarray, cell_m: float, sums: np.ndarray, counts: np.ndarray, semantic: np.ndarray) -> None:
        """Set the votes of the voxels ``keys`` (N,) int64, unique and sorted, at integer indices
        ``ijk`` (N, 3) (centre = ijk * voxel_m metres), voting for ``classes`` (N,) int with
        confidence ``conf`` (N,) float32; voxels outside the n x n map of corner ``origin`` (2,)
        metres and cell edge ``cell_m`` are skipped. Updates ``sums`` (K, n*n) float32,
        ``counts`` (K, n*n) int32 and ``semantic`` (K, n, n) float32 (= sums / counts) in place."""
        k, ncell = sums.shape
        n = int(round(ncell ** 0.5))
        # the kernel indexes without bounds checks: what it indexes with is checked here
        if counts.shape != sums.shape or semantic.shape != (k, n, n) or n * n != ncell:
            raise ValueError(f"sums / counts (K, n*n) and semantic (K, n, n) disagree: {sums.shape}, {counts.shape}, "
                             f"{semantic.shape}")
        if not all(a.flags.c_contiguous and a.dtype == t for a, t in
                   ((sums, np.float32), (counts, np.int32), (semantic, np.float32))):
            raise ValueError("sums / semantic must be contiguous float32 and counts contiguous int32 (updated in place)")
        if not len(keys) == len(ijk) == len(classes) == len(conf) or ijk.shape[1:] != (3,):
            raise ValueError(f"keys (N,), ijk (N, 3), classes (N,), conf (N,) disagree: {len(keys)}, {ijk.shape}, "
                             f"{len(classes)}, {len(conf)}")
        if len(keys) > 1 and not (keys[1:] > keys[:-1]).all():   # the merge needs them unique and sorted
            raise ValueError("vote keys must be unique and sorted")
        if len(classes) and not 0 <= int(classes.min()) <= int(classes.max()) < k:
            raise ValueError(f"vote classes must be in [0, {k}), got {int(classes.min())}..{int(classes.max())}")
        if len(self._slot) != k * ncell:   # (zeros: pages the votes never touch are never allocated)
            self._slot = np.zeros(k * ncell, np.int32)
        self.keys, self.cells, self.classes, self.conf = _vote(
            np.ascontiguousarray(keys, np.int64), np.ascontiguousarray(ijk, np.int64),
            np.ascontiguousarray(classes, np.int64), np.ascontiguousarray(conf, np.float32), float(voxel_m),
            np.asarray(origin, np.float64), float(cell_m), n, self.keys, self.cells, self.classes, self.conf,
            sums.reshape(-1), counts.reshape(-1), semantic.reshape(-1), self._slot)


@compiled
def _vote(keys, ijk, classes, conf, voxel_m, origin, cell_m, n, vkeys, vcells, vclasses, vconf,
          sums, counts, semantic, slot):
    """``VoxelVotes.vote`` on flat arrays; returns the merged (keys, cells, classes, conf)."""
    m, total = len(vkeys), len(keys)
    ncell = n * n
    out_k = np.empty(m + total, np.int64)
    out_c = np.empty(m + total, np.int64)
    out_l = np.empty(m + total, np.int16)
    out_f = np.empty(m + total, np.float32)
    # the replaced votes and the new ones, as (bin, weight, count) entries in bincount's order
    old_bins = np.empty(total, np.int64)
    old_conf = np.empty(total, np.float32)
    new_bins = np.empty(total, np.int64)
    new_conf = np.empty(total, np.float32)
    n_old = n_new = 0
    j = o = 0
    for i in range(total):
        x = np.int64(np.floor((ijk[i, 0] * voxel_m - origin[0]) / cell_m))   # projection.cell_of, op for op
        y = np.int64(np.floor((ijk[i, 1] * voxel_m - origin[1]) / cell_m))
        if not (0 <= x < n and 0 <= y < n):
            continue
        cell = y * n + x
        key = keys[i]
        while j < m and vkeys[j] < key:   # the older votes before this key stay as they are
            out_k[o], out_c[o], out_l[o], out_f[o] = vkeys[j], vcells[j], vclasses[j], vconf[j]
            j += 1
            o += 1
        if j < m and vkeys[j] == key:     # a vote replaced: subtract it
            old_bins[n_old] = np.int64(vclasses[j]) * ncell + vcells[j]
            old_conf[n_old] = vconf[j]
            n_old += 1
            j += 1
        out_k[o], out_c[o], out_l[o], out_f[o] = key, cell, np.int16(classes[i]), conf[i]
        o += 1
        new_bins[n_new] = classes[i] * ncell + cell
        new_conf[n_new] = conf[i]
        n_new += 1
    while j < m:
        out_k[o], out_c[o], out_l[o], out_f[o] = vkeys[j], vcells[j], vclasses[j], vconf[j]
        j += 1
        o += 1
    # per touched bin (in first-touch order): its float64 sum and count; slot[bin] = its index + 1
    touched = np.empty(n_old + n_new, np.int64)
    acc = np.zeros(n_old + n_new, np.float64)
    cnt = np.zeros(n_old + n_new, np.int64)
    n_touched = 0
    for e in range(n_old + n_new):
        if e < n_old:
            b, w, c = old_bins[e], -np.float64(old_conf[e]), -1
        else:
            b, w, c = new_bins[e - n_old], np.float64(new_conf[e - n_old]), 1
        if slot[b] == 0:
            touched[n_touched] = b
            n_touched += 1
            slot[b] = n_touched
        t = slot[b] - 1
        acc[t] += w
        cnt[t] += c
    for t in range(n_touched):   # every touched bin, as numpy applies every unique bin
        b = touched[t]
        sums[b] = sums[b] + np.float32(acc[t])
        counts[b] = counts[b] + np.int32(cnt[t])
        semantic[b] = np.float32(sums[b] / max(counts[b], 1)) if counts[b] > 0 else np.float32(0.0)
        slot[b] = 0
    return out_k[:o], out_c[:o], out_l[:o], out_f[:o]
