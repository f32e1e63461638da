"""``calnav map ... --rerun``: the fused recording as ``map.rrd`` (the ``[viz]`` extra).

Timeline ``frame`` (the recording's frame numbers): ``world/camera`` (pose, pinhole) with
``world/camera/rgb`` (JPEG) and ``world/camera/depth`` (mm) -- thumbnails of at most
``THUMB_WIDTH`` pixels, kept while fusing (the map is fused in memory and written only once
every frame was read, so the recording is written with the other results). Static (the final
map): ``world/map/class`` / ``world/map/confidence`` (``common.rerun_io.log_voxels``) and, with
a labelled mesh, ``world/map/correct`` / ``world/map/wrong`` -- the labelled voxels whose arg-max
class is right / wrong, each coloured by its confidence (the paper's Fig. 1 / 5 in 3D: an
over-confident map shows bright wrong voxels), with the confidences as a ``confidence`` column
-- and ``world/mesh`` (the labelled mesh, vertices coloured by class; its vertices as points
when the PLY has no faces).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

THUMB_WIDTH = 160   # pixels: the frames are context, the map is the subject


@dataclass
class FrameLog:
    """What the recording keeps of each fused frame: number, pose (4, 4), thumbnail intrinsics
    (3, 3), rgb (h, w, 3) uint8 and depth (h, w) uint16 mm thumbnails."""

    frames: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)

    def tap(self, frames: Iterable) -> Iterator:
        """Yield ``frames`` (``SegmentedFrame``) unchanged, keeping a thumbnail of each."""
        for f in frames:
            h, w = f.depth.shape
            s = max(1, -(-w // THUMB_WIDTH))
            k = f.k.copy()
            k[:2] /= s
            k[:2, 2] = (f.k[:2, 2] + 0.5) / s - 0.5   # pixel centres of the subsampled grid
            rgb = np.ascontiguousarray(f.rgb[::s, ::s])
            depth = np.round(np.nan_to_num(f.depth[::s, ::s]) * 1000).clip(0, 65535).astype(np.uint16)
            self.frames.append((int(f.index), np.asarray(f.pose, np.float64), k, rgb, depth))
            yield f


def write_map_recording(path: Path, log: FrameLog, coords: np.ndarray, probs: np.ndarray, class_names,
                        voxel_size_m: float, labels: np.ndarray | None = None, ply: Path | None = None,
                        gt: tuple[np.ndarray, np.ndarray] | None = None) -> Path:
    """Write ``map.rrd`` (module docstring). labels (N,) int per voxel (-1 unlabelled) from the
    labelled mesh ``ply`` whose (vertices, classes) are ``gt``."""
    from calnav.agent.visualize import class_palette
    from calnav.common import rerun_io

    rr = rerun_io.require_rerun("--rerun")
    palette = class_palette(len(class_names))
    rec = rerun_io.new_recording("calnav map", path, class_names, palette)
    for index, pose, k, rgb, depth in log.frames:
        rec.set_time("frame", sequence=index)
        rerun_io.log_camera(rec, "world/camera", pose, k, rgb.shape[1], rgb.shape[0])
        rec.log("world/camera/rgb", rerun_io.jpeg_image(rgb, 85))
        rec.log("world/camera/depth", rr.DepthImage(depth, meter=1000.0))
    if log.frames:
        rec.log("world/trajectory", rr.LineStrips3D([np.stack([p[:3, 3] for _, p, _, _, _ in log.frames])]),
                static=True)
    rerun_io.log_voxels(rec, "world/map", coords, probs, voxel_size_m, palette, static=True)
    if labels is not None and len(probs):
        pred, conf = probs.argmax(axis=1), probs.max(axis=1).astype(np.float32)
        for name, sel in (("correct", (labels >= 0) & (pred == labels)), ("wrong", (labels >= 0) & (pred != labels))):
            rerun_io.log_mask_points(rec, f"world/map/{name}", coords[sel],
                                     rerun_io.confidence_colours(conf[sel], len(class_names)), voxel_size_m,
                                     {"confidence": conf[sel]}, static=True)
    if gt is not None:
        _log_mesh(rec, rr, ply, gt, palette)
    rec.flush()
    rec.disconnect()
    return path


def _log_mesh(rec, rr, ply: Path | None, gt: tuple[np.ndarray, np.ndarray], palette: np.ndarray) -> None:
    """The labelled mesh, vertex colours by class (void grey)."""
    vertices, classes = gt
    colours = np.where((classes >= 0)[:, None], palette[np.clip(classes, 0, len(palette) - 1)], 128).astype(np.uint8)
    faces = None
    if ply is not None:
        from plyfile import PlyData

        data = PlyData.read(str(ply))
        if "face" in data:
            faces = np.stack([np.asarray(f, np.int64) for f in data["face"].data["vertex_indices"]])
    if faces is not None and faces.ndim == 2 and faces.shape[1] == 3:
        rec.log("world/mesh", rr.Mesh3D(vertex_positions=vertices.astype(np.float32), triangle_indices=faces.astype(np.uint32),
                                        vertex_colors=colours), static=True)
    else:
        rec.log("world/mesh", rr.Points3D(vertices.astype(np.float32), colors=colours, radii=0.01), static=True)
