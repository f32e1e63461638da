"""Semantic TSDF voxel map: Open3D's ``VoxelBlockGrid`` (tsdf, weight, colour by the stock
``integrate``) plus the fusion strategy's semantic accumulators in one extra float32
attribute ``semantic``: the channels of ``A`` (K), ``B`` (K), ``W`` (1) --
whichever the strategy needs, in that order -- then the observation count (1). One attribute
means one scattered write per voxel and frame.

Semantic update of one frame (CPU, zero-copy numpy views of the grid; the per-observation
loops are compiled, ``mapping.semantic_kernels``, the softmax / log are torch's):
1. candidate voxels: every ``stride``-th pixel is back-projected; the voxel *containing* the
   surface point is a candidate (so its centre lies within half a voxel diagonal of the
   observed surface). Duplicates are removed with a per-voxel "stamp" array (O(n), no sort):
   one observation per voxel per frame.
2. association: the voxel centre is projected into the image; its pixel provides the logits,
   kept when |voxel z - measured depth| <= ``association_band_voxels`` (rejects occlusion
   edges; grazing surfaces keep a generous band).
3. only the gathered rows (n, K) are scaled and softmax-ed; sample weights come from the
   voxel's camera distance and the depth-image incidence angle (both rounded to float16, the
   observation cache's precision, so a map and a ``fuse`` over its cache agree); the
   strategy's weighted increments are added into the accumulators in one scatter pass.
The hashmap may reallocate when it grows: attribute views are re-fetched on every call.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
import open3d as o3d
import open3d.core as o3c
import torch

from calnav.common.threads import single_threaded_torch
from calnav.mapping import frame_geometry as fg
from calnav.mapping.config import MappingConfig
from calnav.mapping import semantic_kernels as kernels
from calnav.mapping.fusion import ObservationTerms, get_strategy
from calnav.mapping.glfs import GLFSParams
from calnav.mapping import map_readout
from calnav.mapping.map_readout import PointCloud
from calnav.mapping.scaling import as_temperature, scale_logits
from calnav.mapping.weighting import WeightingParams, lut_cells, lut_table, needs_geometry, resolve, sample_weights

BASE_ATTRS = (("tsdf", 1), ("weight", 1), ("color", 3))
SEM = "semantic"
MIB = float(1 << 20)
MIN_BLOCKS = 16
NORMAL_BASE_WIDTH_PX = 160  # auto depth-normal baseline: 1 pixel per 160 pixels of image width
# Open3D keeps voxels with weight strictly above its threshold; stock TSDF weights count whole
# observations, so "at least w observations" is threshold w - 1/2.
WEIGHT_STRICT_OFFSET = 0.5
NO_VOXELS = (np.zeros((0, 3), np.int32), np.zeros(0, np.int64))   # ``frame_voxels`` of a frame that fused none
NO_BLOCK_TOUCHED = "No block is touched"  # Open3D's error for a frame that touches no voxel block


@dataclass
class _Observations:
    """A frame's semantic observations before they are added: table ids (n,) and keys (n, 3) int32
    of the voxels, the table, the scaled logits z, log-probabilities and probabilities (n, K) float32 (the latter
    two (0, K) where the strategy needs none), the sample weights (n,) float32 (without the
    LUT's class factor), the LUT cells (n,) int64 (``lut`` weighting, else empty) and the cache
    record (or None)."""

    ids: np.ndarray
    keys: np.ndarray
    table: fg.BlockTable
    z: np.ndarray
    log_p: np.ndarray
    p: np.ndarray
    weight: np.ndarray
    cell: np.ndarray
    record: tuple | None


class ObservationRecorder(Protocol):
    """What the map's optional ``obs_cache`` must provide (``mapping.calibration.obs_cache.ObsCache``
    does; the online map does not import the calibration package)."""

    @property
    def num_classes(self) -> int: ...

    @property
    def voxel_size_m(self) -> float: ...

    def record(self, voxel_keys: np.ndarray, logits: np.ndarray, distance_m: np.ndarray, angle_deg: np.ndarray,
               weights: np.ndarray | None = None) -> None:
        """One observation per row: voxel_keys (n, 3) int32, logits (n, K) float32, distance_m
        (n,) metres, angle_deg (n,) degrees (both float16-rounded), weights (n,) or None."""


class SemanticVoxelMap:
    """A TSDF + semantic voxel map. ``num_classes`` K; ``cfg`` the mapping config.

    glfs_params: GLFS tau/G/eps/M (for ``glfs``, and M for ``lut`` weighting); default from
    ``cfg.glfs_params`` or identity. temperature: scalar or (K,) logit temperature for the
    other strategies (default ``cfg.temperature``). obs_cache: an ``ObservationRecorder``
    (e.g. ``mapping.calibration.obs_cache.ObsCache``) that records every observation.
    tsdf: False = semantics only, for owners that never read geometry (the agent): only the
    blocks that hold a frame's semantic observations are allocated (not the TSDF's band around
    the surface: ~2x fewer), the semantic accumulators of the observed voxels are bit-identical,
    there is no TSDF pass nor buffers, and the read-outs that need the surface (``voxels``,
    ``point_cloud``, ``voxel_normals``, ``render_semantics``) refuse the map (``observed_voxels``).
    """

    def __init__(self, num_classes: int, cfg: MappingConfig | None = None, device: str = "CPU:0", *,
                 class_names: tuple[str, ...] = (), glfs_params: GLFSParams | None = None,
                 temperature=None, obs_cache: ObservationRecorder | None = None, tsdf: bool = True):
        self.tsdf = bool(tsdf)
        self.cfg = cfg = cfg or MappingConfig()
        if o3c.Device(device).get_type() != o3c.Device.DeviceType.CPU:
            raise ValueError(f"SemanticVoxelMap runs on CPU (zero-copy numpy views), got device {device!r}")
        self.num_classes = k = int(num_classes)
        if k < 2 or (class_names and len(class_names) != k):
            raise ValueError(f"need K >= 2 classes and one name per class, got K = {k}, {len(class_names)} names")
        self.class_names = tuple(class_names)
        self.strategy = get_strategy(cfg.fusion)
        self.weighting = resolve(cfg.weighting, cfg.fusion)
        self._set_fusion_params(glfs_params, temperature)
        self.obs_cache = obs_cache
        if obs_cache is not None and (obs_cache.num_classes != k or abs(obs_cache.voxel_size_m - cfg.voxel_size_m) > 1e-9):
            raise ValueError("obs_cache has another K or voxel size than the map")
        self._slices, start = {}, 0
        for a, c in self.strategy.channels(k).items():
            self._slices[a] = slice(start, start + c)
            start += c
        self._count_ch = start  # last channel: observations per voxel
        self._kernel_args = self._accumulate_constants()
        self._no_cell, self._no_rows = np.zeros(0, np.int64), np.zeros((0, k), np.float32)
        attrs = (dict(BASE_ATTRS) if tsdf else {}) | {SEM: start + 1}   # semantics only: no TSDF buffers
        self.channels = sum(attrs.values())
        self._attr_names = tuple(attrs)
        res = cfg.block_resolution
        self.bytes_per_block = res ** 3 * self.channels * 4
        blocks = cfg.block_count or max(MIN_BLOCKS, int(cfg.initial_alloc_mb * MIB / self.bytes_per_block))
        self.vbg = o3d.t.geometry.VoxelBlockGrid(
            list(attrs), [o3c.float32] * len(attrs), [o3c.SizeVector([c]) for c in attrs.values()],
            cfg.voxel_size_m, res, blocks, o3c.Device(device))
        self._res3 = res ** 3
        self._shift = res.bit_length() - 1
        self._stamp = np.empty(0, np.int32)
        self._grids: dict = {}
        self._intrinsics = fg.IntrinsicsCache()
        self.frames_integrated = 0
        # the voxels the last ``integrate`` fused an observation into (their fused values changed):
        # keys (n, 3) int32 and flat buffer indices (n,) int64, valid until the next integrate
        self.frame_voxels: tuple[np.ndarray, np.ndarray] = NO_VOXELS

    def _set_fusion_params(self, params: GLFSParams | None, temperature) -> None:
        """Temperature, GLFS gates and weighting parameters (the LUT from the GLFS params)."""
        cfg, k = self.cfg, self.num_classes
        if params is None and (self.strategy.gated or self.weighting == "lut"):
            params = GLFSParams.load(cfg.glfs_params) if cfg.glfs_params else GLFSParams.identity(k, self.class_names)
        if params is not None:
            if self.class_names:
                params.check_classes(self.class_names)
            elif params.num_classes != k:
                raise ValueError(f"GLFS params are for {params.num_classes} classes, the map has {k}")
        self.glfs_params = params
        self._g = self._eps = None
        if self.strategy.gated:
            if temperature is not None:
                raise ValueError("glfs takes its temperatures from glfs_params.tau, not from temperature=")
            t = params.torch_tensors()
            tau, self._g, self._eps = t["tau"], t["g"], t["eps"]
        else:
            tau = cfg.temperature if temperature is None else temperature
        self._tau = as_temperature(tau, k)
        edges = {"distance_edges": params.distance_edges, "angle_edges_deg": params.angle_edges_deg} if params else {}
        self._wparams = WeightingParams.from_config(cfg, lut=torch.as_tensor(params.M) if params else None, **edges)

    def _accumulate_constants(self) -> tuple:
        """``semantic_kernels.accumulate``'s per-map arguments (after ``weight, cell``): the flat LUT
        (empty unless ``lut`` weighting), its cells per class, the channel offsets, the vote flag."""
        lut = lut_table(self._wparams).reshape(-1) if self.weighting == "lut" else torch.zeros(0)
        off = {a: self._slices[a].start if a in self._slices else -1 for a in ("A", "B", "W")}
        return (np.ascontiguousarray(lut.detach().numpy(), dtype=np.float32), len(lut) // self.num_classes,
                off["A"], off["B"], self.strategy.votes, off["W"], self._count_ch)

    def reset(self) -> "SemanticVoxelMap":
        """Empty the map in place, keeping its allocation (growing Open3D's hashmap re-creates and
        copies its buffer: ~1 s per doubling at K = 18, GLFS), and return it. Open3D zero-fills
        values only on creation, so the used blocks are zeroed and their keys erased: the next
        episode fuses into a map indistinguishable from a new one."""
        hm = self.vbg.hashmap()
        active = hm.active_buf_indices()
        if active.shape[0]:
            rows = active.numpy().astype(np.int64)
            for name in self._attr_names:   # (capacity, res^3 * C) views; zero the used blocks
                a = self.vbg.attribute(name).numpy()
                a.reshape(a.shape[0], -1)[rows] = 0
            hm.erase(hm.key_tensor()[active.to(o3c.int64)])
        self.frames_integrated = 0
        self.frame_voxels = NO_VOXELS
        return self

    @property
    def has_geometry(self) -> bool:
        """The map integrates depth into its TSDF (``tsdf``): it has a surface to read."""
        return self.tsdf

    # ----------------------------------------------------------------- storage interface
    # (what the read-outs, ``mapping.map_readout``, may use; flat = a voxel's row in the buffers)
    def attribute(self, name: str) -> np.ndarray:
        """(capacity * res^3, C) float32 numpy view of an attribute (shares the grid's memory)."""
        a = self.vbg.attribute(name).numpy()
        return a.reshape(-1, a.shape[-1])

    def observation_counts(self, flat: np.ndarray) -> np.ndarray:
        """(n,) float32 semantic observation count of voxels at flat buffer indices."""
        return self.attribute(SEM)[flat, self._count_ch]

    def fused_probs(self, flat: np.ndarray) -> np.ndarray:
        """(n, K) float32 fused probabilities of voxels at flat buffer indices ``flat``."""
        idx = torch.from_numpy(np.asarray(flat, dtype=np.int64))
        rows = torch.from_numpy(self.attribute(SEM)).index_select(0, idx)
        acc = {a: rows[:, sl] for a, sl in self._slices.items()}
        with torch.no_grad():
            return self.strategy.readout(acc, g=self._g, eps=self._eps).numpy()

    def flat_indices(self, keys: np.ndarray) -> np.ndarray:
        """(n,) int64 flat buffer index of integer voxel keys (n, 3), -1 where not allocated."""
        keys = np.asarray(keys, dtype=np.int32).reshape(-1, 3)
        if len(keys) == 0:
            return np.zeros(0, np.int64)
        res = self.cfg.block_resolution
        blocks, local = keys >> self._shift, keys & (res - 1)
        buf, found = self.vbg.hashmap().find(o3c.Tensor(np.ascontiguousarray(blocks)))
        flat = buf.numpy().astype(np.int64) * self._res3 + local[:, 0] + res * (local[:, 1] + res * local[:, 2])
        return np.where(found.numpy(), flat, -1)

    # ----------------------------------------------------------------- integrate
    def integrate(self, depth: np.ndarray, intrinsics: np.ndarray, pose: np.ndarray, logits=None,
                  rgb: np.ndarray | None = None, weights: np.ndarray | None = None) -> None:
        """Fuse one frame. depth (H, W) float32 m; intrinsics (3, 3); pose (4, 4) world-from-
        camera (OpenCV axes); logits (H, W, K) float32 or None (geometry only); rgb (H, W, 3)
        uint8 or None; weights (H, W) float32 >= 0 per-pixel sample weights (multiply the
        configured weighting) or None."""
        cfg = self.cfg
        # every check comes before the first change to the map: a rejected frame leaves it untouched
        depth, logits, rgb, weights = fg.check_frame(depth, logits, rgb, weights, self.num_classes)
        intr = self._intrinsics(intrinsics, depth.shape[1], depth.shape[0])
        pose = fg.check_pose(pose)
        depth = fg.clean_depth(depth, cfg.depth_min_m, cfg.depth_max_m)
        self.frame_voxels = NO_VOXELS
        if not depth.any():  # nothing valid to integrate (Open3D would raise)
            self.frames_integrated += 1
            return
        intr_o3d, extr = o3c.Tensor(intr), o3c.Tensor(fg.invert_rigid(pose))
        dimg = o3d.t.geometry.Image(o3c.Tensor.from_numpy(depth))
        try:   # (the touched blocks only: nothing is allocated before integrate)
            blocks = self.vbg.compute_unique_block_coordinates(dimg, intr_o3d, extr, 1.0, cfg.depth_max_m,
                                                               cfg.trunc_voxels)
        except RuntimeError as exc:
            # Open3D aborts a frame whose few valid depth pixels touch no voxel block (e.g.
            # facing a wall just beyond min depth): such a frame has nothing to fuse.
            if NO_BLOCK_TOUCHED not in str(exc):
                raise
            self.frames_integrated += 1
            return
        observations = None
        if logits is not None and blocks.shape[0] > 0:
            with single_threaded_torch():   # small tensors: extra torch threads only contend with Open3D's
                observations = self._observe(depth, intr, pose, logits, weights, blocks)   # checks the logits read
        # (semantics only: no TSDF pass; ``_fuse`` allocates the blocks holding observations)
        if self.tsdf and rgb is None:
            self.vbg.integrate(blocks, dimg, intr_o3d, extr, 1.0, cfg.depth_max_m, cfg.trunc_voxels)
        elif self.tsdf:
            cimg = o3d.t.geometry.Image(o3c.Tensor.from_numpy(np.multiply(rgb, np.float32(1 / 255), dtype=np.float32)))
            self.vbg.integrate(blocks, dimg, cimg, intr_o3d, extr, 1.0, cfg.depth_max_m, cfg.trunc_voxels)
        if observations is not None:
            self._fuse(observations, blocks)
        self.frames_integrated += 1

    def _grid(self, intr: np.ndarray, h: int, w: int) -> tuple[fg.PixelGrid, int]:
        """Candidate-pixel grid and depth-normal baseline (pixels) of intrinsics (3, 3) / size."""
        key = (h, w, intr.tobytes())
        if key not in self._grids:
            cfg = self.cfg
            stride = cfg.pixel_stride or fg.auto_stride(intr, cfg.voxel_size_m, cfg.depth_max_m, cfg.sample_spacing_voxels)
            self._grids[key] = (fg.PixelGrid(intr, h, w, stride), cfg.normal_offset_px or max(1, w // NORMAL_BASE_WIDTH_PX))
        return self._grids[key]

    def _candidates(self, depth, intr, pose, blocks) -> tuple[np.ndarray, np.ndarray, "fg.BlockTable"]:
        """Unique candidate voxels of a frame (containing the candidate pixels' back-projected
        points, in its touched blocks): id (n,) int64 in the frame's ``fg.BlockTable``, key (n, 3)
        int32, and the table. Reads nothing of the map: it runs before the frame changes it."""
        res, vox = self.cfg.block_resolution, self.cfg.voxel_size_m
        gr, _ = self._grid(intr, *depth.shape)
        table = fg.BlockTable(blocks.numpy())
        origin, dims = table.low * res, table.dims
        np.take(depth.ravel(), gr.pix, out=gr.depth)
        np.matmul((pose[:3, :3] / vox).astype(np.float32), gr.rays, out=gr.pts)
        size = table.in_frame.size * self._res3
        if len(self._stamp) < size:
            self._stamp = np.empty(size, np.int32)
        # invalid depth is sent far away, into the table's padding
        far = np.float32(2 * self.cfg.depth_max_m + dims.max() * res * vox)
        m = kernels.candidates(gr.pts, gr.depth, far, (pose[:3, 3] / vox - origin + 0.5).astype(np.float32),
                               self._shift, dims.astype(np.int64), table.in_frame, self._stamp, self._res3,
                               origin.astype(np.int32), gr.g, gr.slot, gr.ids, gr.keys)
        return gr.ids[:m], gr.keys[:m], table   # (views of the grid's scratch, valid until the next frame)

    def _observe(self, depth, intr, pose, logits, weights, blocks) -> "_Observations | None":
        """A frame's semantic observations, computed before the frame changes the map: the
        candidate voxels whose pixel sees the same surface (association), the logits they read
        -- ValueError if any is NaN or inf, so a rejected frame leaves the map untouched -- and
        the strategy's per-observation terms. None when no voxel is associated."""
        cfg = self.cfg
        h, w = depth.shape
        ids, keys, table = self._candidates(depth, intr, pose, blocks)
        rot, t = pose[:3, :3].astype(np.float32), pose[:3, 3].astype(np.float32)
        pc = (keys.astype(np.float32) * np.float32(cfg.voxel_size_m) - t) @ rot   # camera frame (n, 3)
        sel, pix, dist_m = (np.empty(len(ids), dtype) for dtype in (np.int64, np.int64, np.float32))
        m = kernels.associate(pc, intr[0, 0], intr[0, 1], intr[0, 2], intr[1, 1], intr[1, 2], w, h, depth.ravel(),
                              np.float32(cfg.association_band_voxels * cfg.voxel_size_m), sel, pix, dist_m)
        if m == 0:
            return None
        sel, pix = sel[:m], pix[:m]
        rows = np.empty((m, self.num_classes), np.float32)
        if not kernels.gather_rows(logits.reshape(h * w, self.num_classes), pix, rows):
            raise ValueError("logits contain NaN or inf at pixels the map reads (pixels of valid depth); the frame "
                             "was not integrated")
        dist = angle = None
        if needs_geometry(self.weighting) or self.obs_cache is not None:
            # both rounded to float16, the observation cache's precision (a map and a fuse over its cache agree)
            dist = dist_m[:m].astype(np.float16).astype(np.float32)
            angle = fg.incidence_angles(depth, intr, pix, self._grid(intr, h, w)[1]).astype(np.float16).astype(np.float32)
        ext = None if weights is None else weights.ravel()[pix]
        wt, cell = (np.ones(m, np.float32) if ext is None else ext), self._no_cell
        with torch.no_grad():
            if self.weighting == "lut":   # the class factor is looked up by the kernel, from argmax z
                cell = lut_cells(torch.from_numpy(dist), torch.from_numpy(angle), self._wparams).numpy()
            elif self.weighting != "none":
                wt = sample_weights(self.weighting, None, torch.from_numpy(dist), torch.from_numpy(angle),
                                    self._wparams).numpy() * wt
            terms = ObservationTerms(scale_logits(torch.from_numpy(rows), self._tau), cfg.laplace_mu)
            log_p = terms.log_p.numpy() if "A" in self._slices else self._no_rows
            p = terms.p.numpy() if "B" in self._slices and not self.strategy.votes else self._no_rows
        record = (keys[sel], rows, dist, angle, ext) if self.obs_cache is not None else None
        return _Observations(ids[sel], keys[sel], table, terms.z.numpy(), log_p, p, np.ascontiguousarray(wt, dtype=np.float32),
                             cell, record)

    def _fuse(self, obs: "_Observations", blocks) -> None:
        """Add a frame's observations to the voxels (after ``integrate`` allocated its blocks)."""
        hm, cells = self.vbg.hashmap(), None
        if not self.tsdf:   # allocate the blocks that hold observations (the TSDF pass allocated the frame's)
            cells = obs.table.cells_of(obs.ids, self._res3)
            blocks = o3c.Tensor(obs.table.block_coords(cells))
            hm.activate(blocks)
        buf, found = hm.find(blocks)
        flat = obs.table.flat_indices(obs.ids, np.where(found.numpy(), buf.numpy(), -1), self._res3, cells)
        kernels.accumulate(self.attribute(SEM), flat, obs.z, obs.log_p, obs.p, obs.weight, obs.cell,
                           *self._kernel_args)   # (skips flat -1: a frame block Open3D dropped)
        keep = flat >= 0
        self.frame_voxels = (obs.keys[keep], flat[keep])
        if obs.record is not None:
            self.obs_cache.record(*(None if a is None else a[keep] for a in obs.record))

    @property
    def o3d_weight_threshold(self) -> float:
        """Open3D's (strict) weight threshold for "at least ``cfg.min_tsdf_weight`` observations"."""
        return max(0.0, self.cfg.min_tsdf_weight - WEIGHT_STRICT_OFFSET)

    # ----------------------------------------------------------------- read-outs (mapping.map_readout)
    def voxels(self) -> tuple[np.ndarray, np.ndarray]:
        """Surface voxels with semantics: coords (N, 3) float32 m, probs (N, K) float32."""
        return map_readout.voxels(self)

    def observed_voxels(self) -> tuple[np.ndarray, np.ndarray]:
        """Every voxel with semantic observations (no TSDF band; any map): coords, probs."""
        return map_readout.observed_voxels(self)

    def query(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fused probs (n, K) of the voxels nearest ``points`` (n, 3) m and their observed mask (n,)."""
        return map_readout.query(self, points)

    def query_keys(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``query`` by integer voxel keys (n, 3) int (centre = key * voxel_size_m)."""
        return map_readout.query_keys(self, keys)

    def voxel_normals(self, coords: np.ndarray) -> np.ndarray:
        """(N, 3) float32 unit TSDF-gradient normals at voxel centres ``coords`` (N, 3) m."""
        return map_readout.voxel_normals(self, coords)

    def point_cloud(self) -> PointCloud:
        """Iso-surface points with semantics: points, colours, normals, probs."""
        return map_readout.point_cloud(self)

    def render_semantics(self, intrinsics: np.ndarray, pose: np.ndarray, width: int,
                         height: int) -> tuple[np.ndarray, np.ndarray]:
        """probs (H, W, K) float32 and valid (H, W) bool seen by a camera (see ``map_readout``)."""
        return map_readout.render_semantics(self, intrinsics, pose, width, height)

    # ----------------------------------------------------------------- stats
    def memory_bytes(self, allocated: bool = False) -> int:
        """Bytes of the voxel blocks in use (or allocated, ``allocated=True``)."""
        hm = self.vbg.hashmap()
        return int((hm.capacity() if allocated else hm.size()) * self.bytes_per_block)
