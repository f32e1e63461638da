"""Observation cache: every semantic observation a voxel received while mapping, kept for
offline 3D calibration / GLFS training (the fused map is a function of the temperature, so the
raw observations must be re-fused for every candidate parameter set; paper Sec. V-C).

Per observation: logits (K) float16, camera distance float16 metres, incidence angle float16
degrees, and (only when the map was given per-pixel weights) that weight float32. Per voxel:
integer voxel key (3) int32 -- world centre = key * voxel_size_m -- and later its ground-truth
label. Each voxel keeps at most ``cap`` observations, a uniform random subset of all it received
(reservoir sampling, implemented vectorised as bottom-k random priorities: the ``cap``
observations with the smallest seeded uniform priority survive, which is distributed exactly as
classic reservoir sampling). Kept observations stay in temporal order.

On disk (``save``/``load``): one ``.npz`` in CSR layout -- per-voxel ``offsets`` (N + 1) into
flat per-observation arrays.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from calnav.common.npz import load_versioned_npz, save_versioned_npz

FORMAT_VERSION = 1
DEFAULT_CAP = 256
FP16_MAX = float(np.finfo(np.float16).max)
COMPACT_MIN_OBS = 1 << 20  # never compact below this many stored observations


@dataclass
class PaddedObservations:
    """Observations of N voxels padded to T: logits (N, T, K) float32, mask (N, T) bool (False =
    padding), distance_m (N, T), angle_deg (N, T), weight (N, T) (ones when none were given).

    Test / reference helper (from ``ObsCache.to_padded``): the input of the padded reference
    fusion ``mapping.fusion.fuse`` in the tests; calibration itself uses the flat layout
    (``mapping.calibration.flat_obs.FlatObservations`` with ``fuse_flat``)."""

    logits: torch.Tensor
    mask: torch.Tensor
    distance_m: torch.Tensor
    angle_deg: torch.Tensor
    weight: torch.Tensor


class ObsCache:
    def __init__(self, num_classes: int, voxel_size_m: float, cap: int | None = DEFAULT_CAP, seed: int = 0,
                 class_names: tuple[str, ...] = ()):
        if num_classes < 2:
            raise ValueError(f"need at least 2 classes, got {num_classes}")
        if cap is not None and cap < 1:
            raise ValueError(f"cap must be >= 1 (or None for no cap), got {cap}")
        self.num_classes = int(num_classes)
        self.voxel_size_m = float(voxel_size_m)
        self.cap = cap
        self.seed = int(seed)
        self.class_names = tuple(class_names)
        self.labels: np.ndarray | None = None
        self._rng = np.random.default_rng(seed)
        self._slot_of: dict[int, int] = {}
        self._keys: list[np.ndarray] = []          # chunks of new voxel keys, (n, 3) int32
        self._n_seen = np.zeros(0, dtype=np.int64)
        self._chunks: dict[str, list[np.ndarray]] = {n: [] for n in ("slot", "prio", "logits", "distance", "angle", "weight")}
        self._stored = 0
        self._next_compact = COMPACT_MIN_OBS
        self._has_weight = False
        self._csr: dict[str, np.ndarray] | None = None
        self._loaded = False

    # ------------------------------------------------------------------ recording
    def record(self, voxel_keys: np.ndarray, logits: np.ndarray, distance_m: np.ndarray, angle_deg: np.ndarray,
               weights: np.ndarray | None = None) -> None:
        """Add one observation per row: voxel_keys (n, 3) int, logits (n, K) finite floats,
        distance_m (n,) metres, angle_deg (n,) degrees, weights (n,) or None (= 1)."""
        keys = np.asarray(voxel_keys).astype(np.int32, copy=False).reshape(-1, 3)
        logits = np.asarray(logits)
        n = len(keys)
        if logits.shape != (n, self.num_classes):
            raise ValueError(f"logits must have shape (n, K) = {(n, self.num_classes)}, got {logits.shape}")
        if not np.isfinite(logits).all():
            raise ValueError("observation cache: logits contain NaN or inf")
        if np.abs(logits).max(initial=0.0) > FP16_MAX:
            raise ValueError(f"observation cache: |logits| above {FP16_MAX:g} do not fit float16")
        if self._loaded:
            raise ValueError("a loaded observation cache is read-only; record into a new ObsCache")
        if n == 0:
            return
        self._csr = None
        flat = ((keys[:, 0].astype(np.int64) & 0x1FFFFF) << 42) | ((keys[:, 1].astype(np.int64) & 0x1FFFFF) << 21) \
            | (keys[:, 2].astype(np.int64) & 0x1FFFFF)
        before = len(self._slot_of)
        setdef, slot_of = self._slot_of.setdefault, self._slot_of
        slots = np.fromiter((setdef(k, len(slot_of)) for k in flat.tolist()), dtype=np.int64, count=n)
        new = slots >= before
        if new.any():  # first occurrence of each new slot, in slot order
            _, first = np.unique(slots[new], return_index=True)
            self._keys.append(keys[new][first])
            self._n_seen = np.concatenate([self._n_seen, np.zeros(len(slot_of) - before, np.int64)])
            self.labels = None  # new voxels: labels must be recomputed
        self._n_seen += np.bincount(slots, minlength=len(slot_of))
        c = self._chunks
        c["slot"].append(slots)
        c["prio"].append(self._rng.random(n, dtype=np.float32))
        c["logits"].append(logits.astype(np.float16))
        c["distance"].append(np.asarray(distance_m, dtype=np.float16).reshape(n))
        c["angle"].append(np.asarray(angle_deg, dtype=np.float16).reshape(n))
        if weights is not None:
            if not self._has_weight:  # earlier observations had weight 1
                c["weight"] = [np.ones(len(s), np.float32) for s in c["slot"][:-1]]
                self._has_weight = True
            c["weight"].append(np.asarray(weights, dtype=np.float32).reshape(n))
        elif self._has_weight:
            c["weight"].append(np.ones(n, np.float32))
        self._stored += n
        if self.cap is not None and self._stored >= self._next_compact:
            self._compact()

    def _consolidate(self) -> dict[str, np.ndarray]:
        c = self._chunks
        for name, parts in c.items():
            if len(parts) > 1:
                c[name] = [np.concatenate(parts)]
        return {name: parts[0] for name, parts in c.items() if parts}

    def _compact(self) -> None:
        """Drop, per over-full voxel, all but the ``cap`` smallest-priority observations."""
        data = self._consolidate()
        if self.cap is None:
            return
        if (self._n_seen > self.cap).any():
            slot, prio = data["slot"], data["prio"]
            order = np.lexsort((prio, slot))
            starts = np.searchsorted(slot[order], slot[order], side="left")
            rank = np.arange(len(order)) - starts
            keep = np.sort(order[rank < self.cap])  # back to temporal order
            for name in data:
                self._chunks[name] = [data[name][keep]]
            self._stored = len(keep)
        self._next_compact = max(COMPACT_MIN_OBS, 2 * self._stored)

    # ------------------------------------------------------------------ access
    def _require(self) -> dict[str, np.ndarray]:
        if self._csr is None:
            if self._stored == 0:
                raise ValueError("observation cache is empty: record observations (map with a cache attached) first")
            self._compact()
            data = self._consolidate()
            order = np.argsort(data["slot"], kind="stable")
            counts = np.bincount(data["slot"], minlength=len(self._slot_of))
            csr = {name: data[name][order] for name in ("logits", "distance", "angle")}
            if self._has_weight:
                csr["weight"] = data["weight"][order]
            csr["offsets"] = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
            csr["keys"] = np.concatenate(self._keys) if self._keys else np.zeros((0, 3), np.int32)
            csr["n_seen"] = self._n_seen
            self._csr = csr
        return self._csr

    def __len__(self) -> int:
        return len(self._slot_of) if self._csr is None else len(self._csr["keys"])

    @property
    def num_observations(self) -> int:
        return int(self._require()["offsets"][-1])

    @property
    def keys(self) -> np.ndarray:
        """(N, 3) int32 integer voxel keys."""
        return self._require()["keys"]

    @property
    def coords(self) -> np.ndarray:
        """(N, 3) float32 voxel centres, world metres."""
        return (self.keys.astype(np.float64) * self.voxel_size_m).astype(np.float32)

    def counts(self) -> np.ndarray:
        """(N,) observations kept per voxel."""
        return np.diff(self._require()["offsets"])

    def n_seen(self) -> np.ndarray:
        """(N,) observations received per voxel (before the cap)."""
        return self._require()["n_seen"]

    def set_labels(self, labels: np.ndarray) -> None:
        labels = np.asarray(labels).astype(np.int64).reshape(-1)
        if len(labels) != len(self.keys):
            raise ValueError(f"need one label per cached voxel ({len(self.keys)}), got {len(labels)}")
        self.labels = labels

    def label_from_mesh(self, vertices, triangles, tri_class, max_dist_m: float | None = None) -> np.ndarray:
        """Ground-truth label per voxel from a labelled mesh (``mapping.ground_truth``)."""
        from calnav.mapping.ground_truth import voxel_labels

        self.set_labels(voxel_labels(self.coords, vertices, triangles, tri_class, max_dist_m, self.voxel_size_m))
        return self.labels

    def to_padded(self, max_T: int | None = None, voxel_ids: np.ndarray | None = None,
                  device: torch.device | str = "cpu") -> PaddedObservations:
        """Observations of the voxels ``voxel_ids`` (default all, in cache order) padded to
        T = min(max_T, most observations). Voxels with more than max_T keep a seeded uniform
        random subset (in temporal order). Chunk big caches with ``voxel_ids``.

        Test / reference helper: only the tests use it (see ``PaddedObservations``); memory
        grows with the busiest voxel, so calibration uses ``FlatObservations.from_caches``."""
        csr = self._require()
        offsets = csr["offsets"]
        ids = np.arange(len(offsets) - 1) if voxel_ids is None else np.asarray(voxel_ids, dtype=np.int64).reshape(-1)
        counts = offsets[ids + 1] - offsets[ids]
        row = np.repeat(np.arange(len(ids)), counts)
        obs = np.repeat(offsets[ids], counts) + (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts))
        t = int(counts.max(initial=0))
        if max_T is not None and t > max_T:
            prio = np.random.default_rng(self.seed).random(len(obs))
            order = np.lexsort((prio, row))
            rank = np.arange(len(order)) - np.searchsorted(row[order], row[order], side="left")
            keep = np.sort(order[rank < max_T])
            row, obs, t = row[keep], obs[keep], max_T
        pos = np.arange(len(row)) - np.searchsorted(row, row, side="left")
        n, k = len(ids), self.num_classes
        logits = np.zeros((n, t, k), np.float32)
        logits[row, pos] = csr["logits"][obs]
        mask = np.zeros((n, t), bool)
        mask[row, pos] = True
        dist = np.zeros((n, t), np.float32)
        dist[row, pos] = csr["distance"][obs]
        angle = np.zeros((n, t), np.float32)
        angle[row, pos] = csr["angle"][obs]
        weight = np.zeros((n, t), np.float32)
        weight[row, pos] = csr["weight"][obs] if "weight" in csr else 1.0
        f = lambda a: torch.from_numpy(a).to(device)  # noqa: E731
        return PaddedObservations(f(logits), f(mask), f(dist), f(angle), f(weight))

    # ------------------------------------------------------------------ file io
    def save(self, path: str | os.PathLike) -> Path:
        csr = self._require()
        meta = {"num_classes": self.num_classes, "voxel_size_m": self.voxel_size_m,
                "cap": self.cap, "seed": self.seed, "class_names": list(self.class_names)}
        arrays = dict(csr)
        if self.labels is not None:
            arrays["labels"] = self.labels
        return save_versioned_npz(path, arrays, meta, FORMAT_VERSION)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "ObsCache":
        arrays, meta = load_versioned_npz(path, FORMAT_VERSION, what="observation cache file")
        cache = cls(meta["num_classes"], meta["voxel_size_m"], meta["cap"], meta["seed"], tuple(meta["class_names"]))
        labels = arrays.pop("labels", None)
        cache._csr = arrays
        cache._loaded = True
        cache._has_weight = "weight" in arrays
        cache._stored = int(arrays["offsets"][-1])
        cache.labels = labels
        return cache
