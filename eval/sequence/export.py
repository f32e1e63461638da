"""``calnav export-sequence``: calnav's own frames written in ScanNet's SensReader layout, so the
sequence readers are tested on data whose answers are known.

Writes ``color/N.jpg`` (JPEG, lossy), ``depth/N.png`` (uint16 millimetres, 0 = invalid),
``pose/N.txt`` (4x4 camera-to-world, 17 significant digits: read back bit-exact),
``intrinsic/intrinsic_color.txt`` and ``intrinsic_depth.txt`` (4x4; the same camera),
``semantic/N.png`` (uint16 class id + 1, 0 = void; for ground-truth based segmenters),
``<scene>_vh_clean_2.labels.ply`` (the house mesh subdivided until no edge is longer than
``--max-edge`` metres, per-vertex ``label`` = class id + 1, 0 = void -- ScanNet's meshes are
dense, and ground truth is read by nearest vertex) and ``label_map.json`` ({label: class name}).
Default: house ``house_val_0000``, its calibration scan (``configs/calibrate_map.yaml``
``scan``), 640x480.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from calnav.common.atomic import write_json_atomic
from calnav.mapping.sequences import SEMANTIC_OFFSET
from dataclasses import dataclass
from calnav.common.ranges import Range
from calnav.eval.arguments import REQUIRED, Command, arg
from calnav.eval.config import CALIBRATION_SECTIONS

DEFAULT_SCENE = "house_val_0000"
DEFAULT_RESOLUTION = "640x480"
DEFAULT_MAX_EDGE_M = 0.05     # longest mesh edge after subdivision, metres (the 5 cm voxel)
JPEG_QUALITY = 95             # cv2.IMWRITE_JPEG_QUALITY of the colour frames, 0-100
MM_PER_M = 1000.0             # depth PNG units: millimetres
MAX_DEPTH_RAW = 65534         # largest valid uint16 depth (65535 means invalid in 7-Scenes)
DEDUP_QUANTUM_M = 1e-4       # vertices closer than this (same class) are merged when densifying, metres
POSE_FMT = "%.17g"            # float64 round-trips exactly through 17 significant digits


def depth_to_mm(depth: np.ndarray) -> np.ndarray:
    """(h, w) float32 metres (0 invalid) -> uint16 millimetres, rounded (0 stays invalid)."""
    mm = np.rint(np.where(np.isfinite(depth), depth, 0.0) * MM_PER_M)
    return np.clip(mm, 0, MAX_DEPTH_RAW).astype(np.uint16)


def densify(vertices: np.ndarray, triangles: np.ndarray, tri_class: np.ndarray, max_edge_m: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split every triangle at the midpoint of its longest edge until no edge exceeds
    ``max_edge_m``. Returns vertices (V, 3) float64, triangles (F, 3) int64 and a class per
    vertex (V,) int64 (the class of its triangles; a vertex shared by two classes is kept once
    per class, so labels do not bleed across class borders)."""
    tri = np.asarray(vertices, np.float64)[np.asarray(triangles)]        # (F, 3, 3) corners
    cls = np.asarray(tri_class).astype(np.int64)
    done_tri, done_cls = [], []
    while len(tri):
        edges = np.stack([tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 1], tri[:, 0] - tri[:, 2]], axis=1)
        length = np.linalg.norm(edges, axis=2)                         # (F, 3): edge i joins corner i, i + 1
        longest = length.argmax(axis=1)
        split = length[np.arange(len(tri)), longest] > max_edge_m
        done_tri.append(tri[~split])                                   # final: never looked at again
        done_cls.append(cls[~split])
        t, e, c_split = tri[split], longest[split], cls[split]
        rows = np.arange(len(t))
        a, b, c = t[rows, e], t[rows, (e + 1) % 3], t[rows, (e + 2) % 3]
        mid = 0.5 * (a + b)   # the same bits from either neighbour: float addition commutes
        tri = np.concatenate([np.stack([a, mid, c], axis=1), np.stack([mid, b, c], axis=1)])
        cls = np.concatenate([c_split, c_split])
    tri, cls = np.concatenate(done_tri), np.concatenate(done_cls)
    corners = tri.reshape(-1, 3)
    _, first, inverse = np.unique(_vertex_keys(corners, np.repeat(cls, 3)), return_index=True, return_inverse=True)
    return corners[first], inverse.reshape(-1, 3).astype(np.int64), np.repeat(cls, 3)[first]


def _vertex_keys(xyz: np.ndarray, cls: np.ndarray) -> np.ndarray:
    """(n,) int64 key per (position quantised to ``DEDUP_QUANTUM_M``, class): equal keys merge
    (an int64 sort is ~15x faster than sorting float rows)."""
    q = np.rint(xyz / DEDUP_QUANTUM_M).astype(np.int64)
    q -= q.min(axis=0)
    dims = q.max(axis=0) + 1
    n_cls = int(cls.max()) + 2   # -1 (void) .. max
    if float(np.prod(dims.astype(np.float64))) * n_cls >= 2.0 ** 62:
        raise ValueError(f"mesh too large to key at {DEDUP_QUANTUM_M} m: extent {(dims * DEDUP_QUANTUM_M).tolist()} m")
    return ((q[:, 0] * dims[1] + q[:, 1]) * dims[2] + q[:, 2]) * n_cls + (cls + 1)


def write_labels_ply(path, vertices: np.ndarray, triangles: np.ndarray, vertex_class: np.ndarray) -> Path:
    """Binary little-endian PLY with per-vertex x, y, z (float32) and ``label`` (uint16 class id
    + 1, 0 = void), and triangle faces. Written directly (header + packed records): plyfile's
    list writer takes ~10 s for a million faces."""
    v = np.empty(len(vertices), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("label", "<u2")])
    v["x"], v["y"], v["z"] = np.asarray(vertices).T
    v["label"] = np.where(vertex_class >= 0, vertex_class + SEMANTIC_OFFSET, 0)
    f = np.empty(len(triangles), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    f["n"], f["i"] = 3, triangles
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
              "property ushort label\n"
              f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n")
    path = Path(path)
    with path.open("wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(v.tobytes())
        fh.write(f.tobytes())
    return path


class ScanNetWriter:
    """Writes frames in ScanNet's SensReader layout under ``root`` (see the module docstring)."""

    def __init__(self, root, k_color: np.ndarray, k_depth: np.ndarray):
        self.root = root = Path(root)
        for d in ("color", "depth", "pose", "intrinsic", "semantic"):
            (root / d).mkdir(parents=True, exist_ok=True)
        for name, k in (("intrinsic_color", k_color), ("intrinsic_depth", k_depth)):
            m = np.eye(4)
            m[:3, :3] = k
            np.savetxt(root / "intrinsic" / f"{name}.txt", m, fmt=POSE_FMT)

    def write(self, index: int, rgb: np.ndarray, depth_m: np.ndarray, pose: np.ndarray,
              semantic: np.ndarray | None = None) -> None:
        """rgb (H, W, 3) uint8, depth_m (h, w) float32 metres, pose (4, 4), semantic (H, W) int or None."""
        import cv2

        root = self.root
        cv2.imwrite(str(root / "color" / f"{index}.jpg"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                    [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        cv2.imwrite(str(root / "depth" / f"{index}.png"), depth_to_mm(depth_m))
        np.savetxt(root / "pose" / f"{index}.txt", np.asarray(pose, np.float64), fmt=POSE_FMT)
        if semantic is not None:
            cv2.imwrite(str(root / "semantic" / f"{index}.png"),
                        np.where(semantic >= 0, semantic + SEMANTIC_OFFSET, 0).astype(np.uint16))


def write_ground_truth(root, scene_name: str, vertices, triangles, tri_class, class_names, max_edge_m: float) -> Path:
    """``<scene>_vh_clean_2.labels.ply`` (densified) and ``label_map.json`` under ``root``."""
    v, t, vc = densify(vertices, triangles, tri_class, max_edge_m)
    path = write_labels_ply(Path(root) / f"{scene_name}_vh_clean_2.labels.ply", v, t, vc)
    write_json_atomic(Path(root) / "label_map.json", {str(i + SEMANTIC_OFFSET): n for i, n in enumerate(class_names)},
                      indent=1)
    return path


def export_house(cfg, scene_id: str, out: Path, seed: int, max_edge_m: float = DEFAULT_MAX_EDGE_M,
                 progress: bool = True) -> int:
    """Render ``scene_id``'s calibration scan under ``cfg`` (a ``Config`` with the calibration sections) into
    ``out`` in ScanNet layout; returns the number of frames."""
    from tqdm import tqdm

    from calnav.eval.calibration.record import HouseScan

    src = HouseScan(cfg, scene_id, seed)
    writer = ScanNetWriter(out, src.intrinsics, src.intrinsics)
    n = 0
    with tqdm(total=len(src), desc=f"export {scene_id}", unit="frame", disable=not progress) as bar:
        for rgb, depth, sem, poses in src.batches(16):
            for i in range(len(rgb)):
                writer.write(n, rgb[i], depth[i], poses[i], sem[i])
                n += 1
                bar.update()
    sc = src.scene
    write_ground_truth(out, scene_id, sc.vertices, sc.triangles, sc.tri_class, src.class_names, max_edge_m)
    return n


def export_sequence_configs(args) -> list:
    """The config ``calnav export-sequence`` runs: ``--resolution`` and ``--frames`` as
    ``env.resolution`` and ``scan.frames`` (the command's shorthands)."""
    from calnav.eval.shorthands import load_command_config

    return [load_command_config(args)]


def main_export_sequence(args, configs) -> None:
    """``configs``: ``export_sequence_configs(args)``, checked by the preflight."""
    from calnav.eval.calibration.record import scene_seed
    from calnav.eval.results_dir import check_output_dir

    cfg = configs[0]
    out = check_output_dir(args.output)
    if out.exists() and any(out.iterdir()) and not args.force:
        raise ValueError(f"{out} is not empty; pass --force to write into it or choose another --output")
    from calnav.envs.scenes import load_scene

    load_scene(args.scene, cfg.env.dataset)   # an unknown scene id fails here, before anything is written
    n = export_house(cfg, args.scene, out, scene_seed(args.scene, cfg.run.seed), args.max_edge)
    w, h = cfg.env.resolution
    print(f"wrote {n} frames of {args.scene} ({w}x{h}) in ScanNet layout to {out}")


@dataclass
class ExportSequenceArgs:
    """``calnav export-sequence``'s flags."""

    scene: str = arg("house_val_0000", "scene id (default: house_val_0000)")
    frames: int | None = arg(None, "scan length, frames; shorthand for scan.frames (default: the config's; 0 = the "
                                   "config's)", sets="scan.frames", convert=lambda n: n or None)   # 0: the config's
    resolution: str | None = arg(None, "frame size WxH, pixels; shorthand for env.resolution (default 640x480)",
                                 sets="env.resolution", sets_default="640x480")
    max_edge: float = arg(0.05, "ground-truth mesh: longest edge after subdivision, metres (default 0.05)",
                          range=Range(0, 10, "metres", lo_open=True))   # > 0: subdivision must end
    output: str = arg(REQUIRED, "output directory (must be empty unless --force)")
    force: bool = arg(False, "write into a non-empty --output")


COMMAND = Command(ExportSequenceArgs, main_export_sequence, export_sequence_configs,
                  config="configs/calibrate_map.yaml",
                  checks=("run",),   # segments nothing; its --scene is loaded first
                  sections=CALIBRATION_SECTIONS)
