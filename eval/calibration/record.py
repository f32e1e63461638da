"""Recording the map-calibration data: each house is scanned once (``envs.trajectories``), every
frame is segmented by each segmenter, and a semantic voxel map with an observation cache
records every voxel observation (logits, distance, incidence angle). Voxels are labelled from
the house mesh. Per house and segmenter two files are written (atomically, so a rerun skips
finished houses):

- ``<scene>.cache.npz``: the ``ObsCache`` (what 3D scaling and GLFS re-fuse);
- ``<scene>.pixels.npz``: ``logits`` (n, K) float16 and ``labels`` (n,) int16 of
  ``pixels_per_frame`` labelled pixels per frame (2D temperature scaling, pixel mECE).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from common.atomic import atomic_path, write_bytes_atomic
from eval.calibration.config import CalibrateMapConfig
from mapping.calibration.obs_cache import ObsCache

SEGMENT_BATCH = 16   # frames per segmenter forward pass
ROLES = ("calib_train", "calib_val", "test")


def role_scene_ids(cfg: CalibrateMapConfig) -> dict[str, list[str]]:
    """{role: scene ids}: procedural houses from the ``calib`` / ``test`` splits, or the user
    scene folders train / val / test when ``env.dataset.scene_dir`` is set."""
    from envs.scenes import split_scene_ids

    st, ds = cfg.study, cfg.env.dataset
    if ds.scene_dir:
        ids = {role: split_scene_ids(split, ds) for role, split in zip(ROLES, ("train", "val", "test"))}
        for role, n in zip(ROLES, (st.calib_train_scenes, st.calib_val_scenes, st.test_scenes)):
            ids[role] = ids[role][:n]
        return ids
    calib = split_scene_ids("calib", dataclasses.replace(ds, calib_scenes=st.calib_train_scenes + st.calib_val_scenes))
    test = split_scene_ids("test", dataclasses.replace(ds, test_scenes=st.test_scenes))
    return {"calib_train": calib[:st.calib_train_scenes], "calib_val": calib[st.calib_train_scenes:], "test": test}


def dataset_for(cfg: CalibrateMapConfig):
    """The dataset config with split sizes large enough for the study's houses."""
    st, ds = cfg.study, cfg.env.dataset
    return dataclasses.replace(ds, calib_scenes=max(ds.calib_scenes, st.calib_train_scenes + st.calib_val_scenes),
                               test_scenes=max(ds.test_scenes, st.test_scenes))


def scene_files(out_dir: Path, segmenter: str, scene_id: str) -> tuple[Path, Path]:
    d = out_dir / "scenes" / segmenter
    return d / f"{scene_id}.cache.npz", d / f"{scene_id}.pixels.npz"


def _scan_frames(cfg: CalibrateMapConfig, scene_id: str, seed: int):
    """(scene, camera intrinsics, poses (F, 4, 4), rgb (F, H, W, 3), depth (F, H, W), semantic (F, H, W))."""
    from envs.navigation import NavGrid
    from envs.render import Camera, Renderer
    from envs.scenes import load_scene
    from envs.trajectories import scan_poses

    env = cfg.env
    scene = load_scene(scene_id, dataset_for(cfg))
    w, h = env.resolution
    camera = Camera(width=w, height=h, hfov_deg=env.hfov_deg)
    renderer = Renderer(scene, camera, min_depth_m=env.min_depth_m, max_depth_m=env.max_depth_m)
    grid = NavGrid.build(scene, env, raycasting_scene=renderer.raycasting_scene)
    poses = scan_poses(scene, grid, env, cfg.scan, seed=seed)
    n = len(poses)
    rgb, depth = np.empty((n, h, w, 3), np.uint8), np.empty((n, h, w), np.float32)
    sem = np.empty((n, h, w), np.int16)
    for i, pose in enumerate(poses):
        fr = renderer.render(pose)
        rgb[i], depth[i] = fr.rgb, fr.depth
        sem[i] = np.where((fr.semantic >= 0) & (fr.semantic < len(scene.class_names)), fr.semantic, -1)
    return scene, camera.intrinsics, poses, rgb, depth, sem


def _save_pixels(path: Path, logits: np.ndarray, labels: np.ndarray) -> None:
    with atomic_path(path) as tmp:
        np.savez_compressed(tmp, logits=logits.astype(np.float16), labels=labels.astype(np.int16))


def record_scene(cfg: CalibrateMapConfig, scene_id: str, segmenters: dict, out_dir: Path, seed: int) -> list[str]:
    """Scan ``scene_id`` and write the cache and pixel files of every segmenter in
    ``segmenters`` ({name: Segmenter}) that has none yet. Returns the names recorded."""
    from mapping.voxel_map import SemanticVoxelMap

    todo = [n for n in segmenters if not all(p.exists() for p in scene_files(out_dir, n, scene_id))]
    if not todo:
        return []
    scene, intrinsics, poses, rgb, depth, sem = _scan_frames(cfg, scene_id, seed)
    rng = np.random.default_rng([seed, 1])
    map_cfg = dataclasses.replace(cfg.mapping, fusion="rbu", weighting="none", glfs_params="")
    k = len(scene.class_names)
    for name in todo:
        seg = segmenters[name]
        if tuple(seg.class_names) != tuple(scene.class_names):
            raise ValueError(f"segmenter {name} predicts classes {seg.class_names}, the scene {scene_id} has {scene.class_names}")
        cache = ObsCache(k, map_cfg.voxel_size_m, cap=cfg.study.cache_cap, seed=seed, class_names=scene.class_names)
        vmap = SemanticVoxelMap(k, map_cfg, class_names=scene.class_names, obs_cache=cache)
        pix_logits, pix_labels = [], []
        for s in range(0, len(poses), SEGMENT_BATCH):
            sl = slice(s, s + SEGMENT_BATCH)
            logits = seg.segment_batch(rgb[sl], depth[sl], semantic=sem[sl], poses=poses[sl])
            for i, lg in enumerate(logits):
                f = s + i
                vmap.integrate(depth[f], intrinsics, poses[f], lg)
                valid = np.flatnonzero(sem[f].ravel() >= 0)
                if len(valid):
                    pick = rng.choice(valid, min(cfg.study.pixels_per_frame, len(valid)), replace=False)
                    pix_logits.append(lg.reshape(-1, k)[pick])
                    pix_labels.append(sem[f].ravel()[pick])
        if len(cache) == 0:
            raise ValueError(f"scan of {scene_id} observed no voxel (empty observation cache)")
        cache.label_from_mesh(scene.vertices, scene.triangles, scene.tri_class)
        cache_path, pix_path = scene_files(out_dir, name, scene_id)
        cache_path.parent.mkdir(parents=True, exist_ok=True)
        _save_pixels(pix_path, np.concatenate(pix_logits), np.concatenate(pix_labels))
        cache.save(cache_path)   # written last: its presence marks the scene done
    return todo


def load_role(out_dir: Path, segmenter: str, scene_ids: list[str]) -> tuple[list[ObsCache], np.ndarray, np.ndarray]:
    """(caches, pixel logits (n, K) float32, pixel labels (n,)) of recorded houses."""
    caches, logits, labels = [], [], []
    for sid in scene_ids:
        cache_path, pix_path = scene_files(out_dir, segmenter, sid)
        caches.append(ObsCache.load(cache_path))
        with np.load(pix_path) as d:
            logits.append(d["logits"].astype(np.float32))
            labels.append(d["labels"].astype(np.int64))
    return caches, np.concatenate(logits), np.concatenate(labels)


@dataclasses.dataclass
class RecordTask:
    """One house to record on a backend worker: the study config (plain dict), the house, the
    segmenters still missing its files, and the scan seed."""

    cfg_dict: dict
    scene_id: str
    segmenters: tuple[str, ...]
    seed: int


_segmenter_cache: dict = {}   # per worker process: (name, device) -> Segmenter, built once


def record_task(task: RecordTask) -> dict[str, bytes]:
    """Record one house in a temporary directory on whichever worker runs it and return its
    files as {path relative to the study directory: bytes}, so the driver writes them and
    workers on other nodes need no shared disk."""
    import tempfile

    from agent.segmenters import make_segmenter
    from eval.config import build_dataclass

    cfg = build_dataclass(CalibrateMapConfig, task.cfg_dict)
    segs = {}
    for name in task.segmenters:
        key = (name, cfg.run.device)
        if key not in _segmenter_cache:
            _segmenter_cache[key] = make_segmenter(name, device=cfg.run.device)
        segs[name] = _segmenter_cache[key]
    with tempfile.TemporaryDirectory(prefix="calnav-record-") as tmp:
        record_scene(cfg, task.scene_id, segs, Path(tmp), task.seed)
        return {str(p.relative_to(tmp)): p.read_bytes() for name in task.segmenters
                for p in scene_files(Path(tmp), name, task.scene_id)}


def record_houses(cfg: CalibrateMapConfig, scene_seeds: dict[str, int], segmenters: tuple[str, ...],
                  out_dir: Path, progress: bool = True) -> None:
    """Record every house of ``scene_seeds`` ({scene id: scan seed}) that lacks a segmenter's
    files, as tasks on the ``run.backend`` backend (houses are the slow stage); each house's
    files are written as it arrives (pixels first, the cache last: its presence marks the
    house done), so a killed study resumes."""
    from tqdm import tqdm

    from eval.backends import make_backend
    from eval.config import to_dict

    backend = make_backend(cfg.run)
    cfg_dict, tasks = to_dict(cfg), []
    for sid, seed in scene_seeds.items():
        missing = tuple(n for n in segmenters if not all(p.exists() for p in scene_files(out_dir, n, sid)))
        if missing:
            tasks.append(RecordTask(cfg_dict, sid, missing, seed))
    bar = tqdm(total=len(scene_seeds), initial=len(scene_seeds) - len(tasks), desc="record scans", unit="house",
               disable=not progress)
    for _, files in backend.map_unordered(record_task, tasks):
        for rel in sorted(files, key=lambda r: r.endswith(".cache.npz")):  # the cache last
            dest = out_dir / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(dest, files[rel])
        bar.update(1)
    bar.close()
