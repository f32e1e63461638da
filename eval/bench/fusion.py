"""Bench section "fusion": speed and memory of calibrated semantic fusion (``mapping``).

Same run, same frames (the BenchContext's house trajectory), every method timed on every frame
in rotating order (so background load hits all methods alike); figures are medians.

- ``fusion.tsdf_only_ms_<res>``: stock Open3D TSDF integrate of the RGB-D frame (block
  coordinates + ``integrate``; the float colour conversion included), no semantics.
- ``fusion.map_geometry_ms_<res>``: ``SemanticVoxelMap.integrate`` without logits (validation,
  depth cleaning, the same stock integrate).
- ``fusion.<S>.ms_<res>`` / ``fusion.<S>.fps_<res>``: full semantic integrate with strategy S
  (default config: sample weighting ``auto`` = GLFS look-up table for glfs, none otherwise).
- ``fusion.<S>.ratio_vs_tsdf``: S time / tsdf-only time at the reference resolution, the
  median over frames of the per-frame ratio (paired, so slow drifts of a shared machine's load
  cancel) (target <= 1.5).
- ``fusion.glfs_vs_rbu``: glfs / rbu time, paired likewise (target <= 1.2).
- ``fusion.mb_per_m2``: MiB of voxel blocks in use (glfs map, K = 18) per m^2 of mapped floor
  (the x-y footprint of the semantic surface voxels, in 5 cm cells); ``fusion.mb_allocated``.
Logits are the ground-truth class image turned into K = 18 scores: N(0, 1) noise plus a
margin of 2 on the true class (noise fixed per resolution, made outside the timed region).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

REFERENCE_RES = (640, 480)
LOW_RES = (160, 120)
LOGIT_NOISE_STD = 1.0
LOGIT_MARGIN = 2.0
SEED = 0
MIB = float(1 << 20)
STOCK_BLOCKS = 4000  # the baseline's initial hashmap capacity (tsdf + weight + colour: 10 KB / block)


@dataclass
class BenchFrames:
    """Frames of one resolution: intrinsics (3, 3) and (depth (H, W) float32 m, rgb (H, W, 3)
    uint8, labels (H, W) int64 class or -1, pose (4, 4) world-from-camera) per frame."""

    intrinsics: np.ndarray
    frames: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]


def frames_from_context(ctx, width: int, height: int, num_classes: int) -> BenchFrames:
    k = np.asarray(ctx.renderer(width, height).camera.intrinsics, dtype=np.float64)
    out = []
    for frame, pose in zip(ctx.frames(width, height), ctx.poses):
        labels = frame.semantic.astype(np.int64)
        labels[(labels < 0) | (labels >= num_classes)] = -1
        out.append((np.ascontiguousarray(frame.depth, dtype=np.float32), frame.rgb, labels, np.asarray(pose)))
    return BenchFrames(k, out)


def run(ctx) -> dict[str, float]:
    from calnav.envs.semantics import NUM_CLASSES

    data = {res: frames_from_context(ctx, *res, NUM_CLASSES) for res in (REFERENCE_RES, LOW_RES)}
    return measure(data, NUM_CLASSES)


class _StockTSDF:
    """Open3D's own TSDF integration (tsdf, weight, colour), the baseline."""

    def __init__(self, cfg):
        import open3d as o3d
        import open3d.core as o3c

        self.o3d, self.o3c, self.cfg = o3d, o3c, cfg
        self.vbg = o3d.t.geometry.VoxelBlockGrid(
            ["tsdf", "weight", "color"], [o3c.float32] * 3, [o3c.SizeVector([c]) for c in (1, 1, 3)],
            cfg.voxel_size_m, cfg.block_resolution, STOCK_BLOCKS, o3c.Device("CPU:0"))

    def integrate(self, depth, k, extrinsic, rgb) -> None:
        o3d, o3c, cfg = self.o3d, self.o3c, self.cfg
        dimg = o3d.t.geometry.Image(o3c.Tensor.from_numpy(depth))
        cimg = o3d.t.geometry.Image(o3c.Tensor.from_numpy(np.multiply(rgb, np.float32(1 / 255), dtype=np.float32)))
        intr, extr = o3c.Tensor(k), o3c.Tensor(extrinsic)
        blocks = self.vbg.compute_unique_block_coordinates(dimg, intr, extr, 1.0, cfg.depth_max_m, cfg.trunc_voxels)
        self.vbg.integrate(blocks, dimg, cimg, intr, extr, 1.0, cfg.depth_max_m, cfg.trunc_voxels)


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return (time.perf_counter() - t0) * 1e3


def measure(data: dict[tuple[int, int], BenchFrames], num_classes: int, cfg=None) -> dict[str, float]:
    """Figures for every resolution in ``data``; the first one is the reference (ratios, memory).
    cfg: base ``MappingConfig`` (default: the defaults); its ``fusion`` is replaced per map."""
    import dataclasses

    from calnav.mapping.config import MappingConfig
    from calnav.mapping.frame_geometry import invert_rigid
    from calnav.mapping.registry import FUSIONS
    from calnav.mapping.voxel_map import SemanticVoxelMap

    out: dict[str, float] = {}
    rng = np.random.default_rng(SEED)
    for i, ((w, h), bf) in enumerate(data.items()):
        res = f"{w}x{h}"
        k = bf.intrinsics
        base = cfg or MappingConfig()
        maps = {s: SemanticVoxelMap(num_classes, dataclasses.replace(base, fusion=s)) for s in FUSIONS}
        geometry_map = SemanticVoxelMap(num_classes, base)
        stock = _StockTSDF(base)
        noise = (rng.standard_normal((h, w, num_classes), dtype=np.float32) * LOGIT_NOISE_STD)
        logits = np.empty_like(noise)
        times: dict[str, list[float]] = {name: [] for name in ["tsdf", "geometry", *FUSIONS]}
        for t, (depth, rgb, labels, pose) in enumerate(bf.frames):
            np.copyto(logits, noise)
            hit = labels >= 0
            logits[hit, labels[hit]] += LOGIT_MARGIN
            clean = np.where(np.isfinite(depth), depth, np.float32(0))
            extrinsic = invert_rigid(pose)
            jobs = {"tsdf": lambda: stock.integrate(clean, k, extrinsic, rgb),
                    "geometry": lambda: geometry_map.integrate(depth, k, pose, None, rgb)}
            for s, m in maps.items():
                jobs[s] = (lambda m=m: m.integrate(depth, k, pose, logits, rgb))
            names = list(jobs)
            for name in names[t % len(names):] + names[: t % len(names)]:  # rotate the order
                times[name].append(_timed(jobs[name]))
        med = {name: float(np.median(v)) for name, v in times.items()}
        paired = {name: np.asarray(v) for name, v in times.items()}  # same frames, same moment
        out[f"fusion.tsdf_only_ms_{res}"] = med["tsdf"]
        out[f"fusion.map_geometry_ms_{res}"] = med["geometry"]
        for s in FUSIONS:
            out[f"fusion.{s}.ms_{res}"] = med[s]
            out[f"fusion.{s}.fps_{res}"] = 1e3 / med[s]
            if i == 0:
                out[f"fusion.{s}.ratio_vs_tsdf"] = float(np.median(paired[s] / paired["tsdf"]))
        if i == 0:
            out["fusion.glfs_vs_rbu"] = float(np.median(paired["glfs"] / paired["rbu"]))
            glfs = maps["glfs"]
            coords, _ = glfs.voxels()
            cells = np.unique(np.floor(coords[:, :2] / glfs.cfg.voxel_size_m).astype(np.int64), axis=0)
            floor_m2 = len(cells) * glfs.cfg.voxel_size_m ** 2
            out["fusion.mb_per_m2"] = glfs.memory_bytes() / MIB / max(floor_m2, np.finfo(float).tiny)
            out["fusion.mb_allocated"] = glfs.memory_bytes(allocated=True) / MIB
            out["fusion.semantic_voxels"] = float(len(coords))
    return out
