"""Semantic TSDF voxel map: Open3D's ``VoxelBlockGrid`` (tsdf, weight, colour by the stock
``integrate``) plus the fusion strategy's semantic accumulators in one extra float32
attribute ``semantic``: the channels of ``A`` (K), ``B`` (K), ``W`` (1) --
whichever the strategy needs, in that order -- then the observation count (1). One attribute
means one scattered write per voxel and frame.

Semantic update of one frame (all vectorised, CPU, zero-copy numpy / torch views of the grid):
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
   strategy's increments are ``index_add_``-ed into the accumulators.
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
from calnav.mapping.fusion import ObservationTerms, get_strategy
from calnav.mapping.glfs import GLFSParams
from calnav.mapping import map_readout
from calnav.mapping.map_readout import PointCloud
from calnav.mapping.scaling import as_temperature, scale_logits
from calnav.mapping.weighting import WeightingParams, needs_geometry, resolve, sample_weights

BASE_ATTRS = (("tsdf", 1), ("weight", 1), ("color", 3))
SEM = "semantic"
MIB = float(1 << 20)
MIN_BLOCKS = 16
NORMAL_BASE_WIDTH_PX = 160  # auto depth-normal baseline: 1 pixel per 160 pixels of image width
# Open3D keeps voxels with weight strictly above its threshold; stock TSDF weights count whole
# observations, so "at least w observations" is threshold w - 1/2.
WEIGHT_STRICT_OFFSET = 0.5
NO_BLOCK_TOUCHED = "No block is touched"  # Open3D's error for a frame that touches no voxel block


@dataclass
class _Observations:
    """A frame's semantic observations before they are added: table ids (n,) of the voxels,
    the table, the accumulator increments (n, C) and the cache record (or None)."""

    ids: np.ndarray
    table: fg.BlockTable
    values: torch.Tensor
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
    tsdf: False = semantics only, for owners that never read geometry (the agent): the frame's
    blocks are allocated as the TSDF step would and the semantic accumulators are bit-identical,
    but there is no TSDF pass nor buffers, and the read-outs that need the surface (``voxels``,
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
        self.frames_integrated = 0

    def _set_fusion_params(self, params: GLFSParams | None, temperature) -> None:
        """Temperature, GLFS gates and weighting parameters (the LUT from the GLFS params)."""
        cfg, k = self.cfg, self.num_classes
        if params is None and (cfg.fusion == "glfs" or self.weighting == "lut"):
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
        intr = fg.check_intrinsics(intrinsics, depth.shape[1], depth.shape[0])
        pose = fg.check_pose(pose)
        depth = fg.clean_depth(depth, cfg.depth_min_m, cfg.depth_max_m)
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
        if not self.tsdf:   # semantics only: the blocks Open3D's integrate would allocate, no TSDF pass
            self.vbg.hashmap().activate(blocks)
        elif rgb is None:
            self.vbg.integrate(blocks, dimg, intr_o3d, extr, 1.0, cfg.depth_max_m, cfg.trunc_voxels)
        else:
            cimg = o3d.t.geometry.Image(o3c.Tensor.from_numpy(np.multiply(rgb, np.float32(1 / 255), dtype=np.float32)))
            self.vbg.integrate(blocks, dimg, cimg, intr_o3d, extr, 1.0, cfg.depth_max_m, cfg.trunc_voxels)
        if observations is not None:
            with single_threaded_torch():
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
        # voxel coordinates relative to the padded corner (float -> int truncation is a floor for
        # points >= 0; anything outside is clipped into the padding, which holds no frame block);
        # invalid depth is sent far away, into the padding too
        np.take(depth.ravel(), gr.pix, out=gr.depth)
        np.copyto(gr.depth, np.float32(2 * self.cfg.depth_max_m + dims.max() * res * vox), where=gr.depth <= 0)
        np.matmul((pose[:3, :3] / vox).astype(np.float32), gr.rays, out=gr.pts)
        gr.pts *= gr.depth
        gr.pts += (pose[:3, 3] / vox - origin + 0.5).astype(np.float32)[:, None]
        np.maximum(gr.pts, 0, out=gr.pts)
        np.copyto(gr.g, gr.pts, casting="unsafe")
        np.right_shift(gr.g, self._shift, out=gr.b)
        np.bitwise_and(gr.g, res - 1, out=gr.loc)
        np.minimum(gr.b, (dims - 1).astype(np.int32)[:, None], out=gr.b)
        lin, local = gr.i32
        np.multiply(gr.b[2], dims[1], out=lin)
        lin += gr.b[1]
        lin *= dims[0]
        lin += gr.b[0]
        np.multiply(gr.loc[2], res, out=local)
        local += gr.loc[1]
        local *= res
        local += gr.loc[0]
        ok = np.flatnonzero(table.in_frame[lin])
        ids = lin[ok].astype(np.int64)
        ids *= self._res3
        ids += local[ok]
        size = table.in_frame.size * self._res3
        if len(self._stamp) < size:
            self._stamp = np.empty(size, np.int32)
        order = np.arange(len(ids), dtype=np.int32)
        self._stamp[ids] = order  # one winner per voxel: O(n) de-duplication, no sort
        win = np.flatnonzero(self._stamp[ids] == order)
        keys = gr.g[:, ok[win]].T + origin.astype(np.int32)
        return ids[win], np.ascontiguousarray(keys), table

    def _observe(self, depth, intr, pose, logits, weights, blocks) -> "_Observations | None":
        """A frame's semantic observations, computed before the frame changes the map: the
        candidate voxels whose pixel sees the same surface (association), the logits they read
        -- ValueError if any is NaN or inf, so a rejected frame leaves the map untouched -- and
        the strategy's increments. None when no voxel is associated."""
        cfg = self.cfg
        h, w = depth.shape
        ids, keys, table = self._candidates(depth, intr, pose, blocks)
        # associate: project voxel centres, keep those whose pixel sees the same surface
        rot, t = pose[:3, :3].astype(np.float32), pose[:3, 3].astype(np.float32)
        pc = (keys.astype(np.float32) * np.float32(cfg.voxel_size_m) - t) @ rot
        x, y, z = pc.T
        inv_z = 1.0 / np.where(z > 0, z, np.float32(1))
        u = np.rint((intr[0, 0] * x + intr[0, 1] * y) * inv_z + intr[0, 2]).astype(np.int64)
        v = np.rint(intr[1, 1] * y * inv_z + intr[1, 2]).astype(np.int64)
        ok = (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        pix = np.where(ok, v * w + u, 0)
        dm = depth.ravel()[pix]
        ok &= (dm > 0) & (np.abs(z - dm) <= cfg.association_band_voxels * cfg.voxel_size_m)
        sel = np.flatnonzero(ok)
        if len(sel) == 0:
            return None
        ids, keys, pix, pc = ids[sel], keys[sel], pix[sel], pc[sel]
        rows = torch.from_numpy(logits.reshape(h * w, self.num_classes)).index_select(0, torch.from_numpy(pix))
        # the logits the map reads must be finite (a sum is finite when every term is, barring
        # overflow; only then a look at each): one pass over these rows, not the whole image
        if not bool(torch.isfinite(rows.sum())) and not bool(torch.isfinite(rows).all()):
            raise ValueError("logits contain NaN or inf at pixels the map reads (pixels of valid depth); the frame "
                             "was not integrated")
        geometry = needs_geometry(self.weighting) or self.obs_cache is not None
        dist = angle = None
        if geometry:
            offset = self._grid(intr, h, w)[1]
            dist = np.sqrt(np.einsum("ij,ij->i", pc, pc)).astype(np.float16).astype(np.float32)
            angle = fg.incidence_angles(depth, intr, pix, offset).astype(np.float16).astype(np.float32)
        with torch.no_grad():
            z_scaled = scale_logits(rows, self._tau)
            if self.weighting == "none":
                wt = torch.ones(len(pix), dtype=torch.float32)
            else:
                pred = z_scaled.max(dim=1).indices if self.weighting == "lut" else None  # (argmax: ~0.4 ms)
                wt = sample_weights(self.weighting, pred, torch.from_numpy(dist), torch.from_numpy(angle), self._wparams)
            ext = None
            if weights is not None:
                ext = weights.ravel()[pix]
                wt = wt * torch.from_numpy(ext)
            inc = self.strategy.increments(ObservationTerms(z_scaled, cfg.laplace_mu), wt)
            val = torch.cat([inc[a] for a in self._slices] + [torch.ones(len(ids), 1)], dim=1)
        record = (keys, rows.numpy(), dist, angle, ext) if self.obs_cache is not None else None
        return _Observations(ids, table, val, record)

    def _fuse(self, obs: "_Observations", blocks) -> None:
        """Add a frame's observations to the voxels (after ``integrate`` allocated its blocks)."""
        buf, found = self.vbg.hashmap().find(blocks)
        flat = obs.table.flat_indices(obs.ids, np.where(found.numpy(), buf.numpy(), -1), self._res3)
        keep = flat >= 0   # every frame block is allocated by then; a block Open3D dropped is skipped
        val = obs.values if keep.all() else obs.values[torch.from_numpy(keep)]
        with torch.no_grad():
            torch.from_numpy(self.attribute(SEM)).index_add_(0, torch.from_numpy(flat[keep]), val)
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
