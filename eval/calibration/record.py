"""Recording the map-calibration data: each house is scanned (``envs.trajectories``), every
frame is segmented by each segmenter, and a semantic voxel map with an observation cache
records every voxel observation (logits, distance, incidence angle). Voxels are labelled from
the house mesh. The frames come from a frame source (``frame_source``): ``HouseScan`` renders a
house's scan batch by batch (once per segmenter: rendering is cheap next to segmenting, and
no scan is held in memory); ``RecordedScan`` reads a recorded sequence of
``sequences.list`` and labels voxels from its labelled mesh. Per house and segmenter two files are written (atomically, so a rerun skips
finished houses):

- ``<scene>.cache.npz``: the ``ObsCache`` (what 3D scaling and GLFS re-fuse);
- ``<scene>.pixels.npz``: ``logits`` (n, K) float16 and ``labels`` (n,) int16 of
  ``pixels_per_frame`` labelled pixels per frame (2D temperature scaling, pixel mECE).
"""
from __future__ import annotations

import dataclasses
import itertools
import zlib
from pathlib import Path

import numpy as np

from calnav.common.atomic import atomic_path, write_bytes_atomic
from calnav.common.prefetch import prefetched
from calnav.eval.config import Config
from calnav.mapping.calibration.obs_cache import ObsCache
from calnav.mapping.sequences import LAYOUTS, Registration, Sequence, SequenceFrame, vertex_ground_truth

SEGMENT_BATCH = 16   # frames per segmenter forward pass
ROLES = ("calib_train", "calib_val", "test")


def role_scene_ids(cfg: Config) -> dict[str, list[str]]:
    """{role: scene ids}: procedural houses from the ``calib`` / ``test`` splits, the user
    scene folders train / val / test when ``env.dataset.scene_dir`` is set, or the recorded
    sequences of ``sequences.list`` (all of them: the study's house counts do not apply)."""
    from calnav.envs.scenes import split_scene_ids

    st, ds = cfg.study, cfg.env.dataset
    if cfg.sequences.list:
        listed = read_sequence_list(cfg.sequences.list, cfg.sequences.layout)
        return {role: [sid for sid, _, _ in listed[role]] for role in ROLES}
    if ds.scene_dir:
        ids = {role: split_scene_ids(split, ds) for role, split in zip(ROLES, ("train", "val", "test"))}
        for role, n in zip(ROLES, (st.calib_train_scenes, st.calib_val_scenes, st.test_scenes)):
            ids[role] = ids[role][:n]
        return ids
    calib = split_scene_ids("calib", dataclasses.replace(ds, calib_scenes=st.calib_train_scenes + st.calib_val_scenes))
    test = split_scene_ids("test", dataclasses.replace(ds, test_scenes=st.test_scenes))
    return {"calib_train": calib[:st.calib_train_scenes], "calib_val": calib[st.calib_train_scenes:], "test": test}



def scene_seed(scene_id: str, base: int) -> int:
    """Per-house trajectory seed (stable across runs and house lists)."""
    return (zlib.crc32(scene_id.encode()) + 7919 * base) % (2 ** 31)


def dataset_for(cfg: Config):
    """The dataset config with split sizes large enough for the study's houses."""
    st, ds = cfg.study, cfg.env.dataset
    return dataclasses.replace(ds, calib_scenes=max(ds.calib_scenes, st.calib_train_scenes + st.calib_val_scenes),
                               test_scenes=max(ds.test_scenes, st.test_scenes))


def scene_files(out_dir: Path, segmenter: str, scene_id: str) -> tuple[Path, Path]:
    d = out_dir / "scenes" / segmenter
    return d / f"{scene_id}.cache.npz", d / f"{scene_id}.pixels.npz"


class HouseScan:
    """Frame source of one procedural (or user) house: its calibration scan (``envs.trajectories``),
    rendered a batch at a time. ``class_names``, ``intrinsics`` (3, 3), ``len()`` frames;
    ``batches(n)`` yields (rgb (B, H, W, 3) uint8, depth (B, H, W) float32 m, semantic (B, H, W)
    int16 class or -1, poses (B, 4, 4) world-from-camera); ``label(cache)`` labels an ``ObsCache``
    from the house mesh. ``RecordedScan`` is the same for a recording."""

    def __init__(self, cfg: Config, scene_id: str, seed: int):
        from calnav.envs.config import require_single_storey
        from calnav.envs.navigation import NavGrid
        from calnav.envs.render import Camera, Renderer
        from calnav.envs.scenes import load_scene
        from calnav.envs.trajectories import scan_poses

        env = cfg.env
        require_single_storey(env, "the map-calibration scans")
        self.scene = scene = load_scene(scene_id, dataset_for(cfg))
        w, h = env.resolution
        camera = Camera(width=w, height=h, hfov_deg=env.hfov_deg)
        self.renderer = Renderer(scene, camera, min_depth_m=env.min_depth_m, max_depth_m=env.max_depth_m)
        grid = NavGrid.build(scene, env, raycasting_scene=self.renderer.raycasting_scene)
        self.poses = scan_poses(scene, grid, env, cfg.scan, seed=seed)
        self.intrinsics = camera.intrinsics
        self.class_names = tuple(scene.class_names)

    def __len__(self) -> int:
        return len(self.poses)

    def batches(self, size: int):
        k = len(self.class_names)
        for s in range(0, len(self.poses), size):
            frames = [self.renderer.render(p) for p in self.poses[s:s + size]]
            sem = np.stack([np.where((f.semantic >= 0) & (f.semantic < k), f.semantic, -1) for f in frames])
            yield (np.stack([f.rgb for f in frames]), np.stack([f.depth for f in frames]), sem.astype(np.int16),
                   self.poses[s:s + size])

    def label(self, cache: ObsCache) -> None:
        cache.label_from_mesh(self.scene.vertices, self.scene.triangles, self.scene.tri_class)


# ---------------------------------------------------------------- recorded sequences
def read_sequence_list(path, default_layout: str = "scannet") -> dict[str, list[tuple[str, Path, str]]]:
    """{role: [(sequence id, directory, layout)]} of a list file: one ``<role> <dir> [layout]``
    per line (``#`` comments; relative directories are relative to the list file). The id is
    the directory name and must be unique."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"sequence list not found: {path}")
    out: dict[str, list] = {r: [] for r in ROLES}
    seen: set[str] = set()
    for n, line in enumerate(path.read_text().splitlines(), 1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        if len(parts) not in (2, 3) or parts[0] not in ROLES:
            raise ValueError(f"{path}:{n}: expected '<role> <dir> [layout]' with role one of {', '.join(ROLES)}, "
                             f"got {line.strip()!r}")
        layout = parts[2] if len(parts) == 3 else default_layout
        if layout not in LAYOUTS:
            raise ValueError(f"{path}:{n}: {LAYOUTS.unknown(layout)}")
        folder = Path(parts[1]) if Path(parts[1]).is_absolute() else path.parent / parts[1]
        if not folder.is_dir():
            raise ValueError(f"{path}:{n}: sequence directory not found: {folder}")
        sid = folder.resolve().name
        if sid in seen:
            raise ValueError(f"{path}:{n}: a second sequence named {sid!r} (ids are directory names)")
        seen.add(sid)
        out[parts[0]].append((sid, folder, layout))
    return out


class RecordedScan:
    """A recorded sequence as a calibrate-map frame source (the interface of ``HouseScan``):
    frames registered to the depth camera; voxel labels from the labelled PLY by nearest vertex."""

    def __init__(self, seq: Sequence, class_names: tuple[str, ...]):
        self.seq, self.class_names = seq, tuple(class_names)
        seq.use_class_names(self.class_names)   # 2D labels from ScanNet's label-filt/ when mapped
        self.intrinsics = seq.k_depth
        self.ply = seq.labelled_ply()
        if self.ply is None:
            raise ValueError(f"{seq.root} has no labelled mesh (*_vh_clean_2.labels.ply) to label its voxels")
        self.vertices, self.vertex_class = vertex_ground_truth(self.ply, self.class_names, seq.cfg, seq.root)

    def __len__(self) -> int:
        return len(self.seq)

    def batches(self, size: int):
        reg = Registration(self.seq.k_color, self.seq.color_size, self.seq.k_depth, self.seq.depth_size)
        batch: list[SequenceFrame] = []
        frames = prefetched(self.seq.frames())
        for fr in itertools.chain(frames, [None]):   # None: flush the last batch
            if fr is not None:
                batch.append(fr)
            if batch and (fr is None or len(batch) == size):
                w, h = self.seq.depth_size
                sem = [np.full((h, w), -1) if f.semantic is None else reg.labels(f.semantic) for f in batch]
                yield (np.stack([reg.rgb(f.rgb) for f in batch]), np.stack([f.depth for f in batch]),
                       np.stack(sem).astype(np.int16), np.stack([f.pose for f in batch]))
                batch = []

    def label(self, cache) -> None:
        from calnav.mapping.ground_truth import nearest_vertex_labels

        cache.set_labels(nearest_vertex_labels(cache.coords, self.vertices, self.vertex_class,
                                               self.seq.cfg.label_distance_m))


def recorded_scan(cfg, scene_id: str) -> RecordedScan | None:
    """The ``RecordedScan`` of ``scene_id`` when ``cfg.sequences.list`` lists it, else None."""
    from calnav.agent.segmenters.base import default_class_names

    if not cfg.sequences.list:
        return None
    for entries in read_sequence_list(cfg.sequences.list, cfg.sequences.layout).values():
        for sid, folder, layout in entries:
            if sid == scene_id:
                seq = Sequence(folder, layout, cfg.sequence)
                seq.check_scale(cfg.mapping.depth_min_m, cfg.mapping.depth_max_m, cfg.mapping.voxel_size_m)
                return RecordedScan(seq, default_class_names())
    return None


def frame_source(cfg: Config, scene_id: str, seed: int):
    """The frames of ``scene_id``: a recorded sequence of ``sequences.list`` when it names one,
    else a calnav house scan."""
    return recorded_scan(cfg, scene_id) or HouseScan(cfg, scene_id, seed)


def _save_pixels(path: Path, logits: np.ndarray, labels: np.ndarray) -> None:
    with atomic_path(path) as tmp:
        np.savez_compressed(tmp, logits=logits.astype(np.float16), labels=labels.astype(np.int16))


def record_scene(cfg: Config, scene_id: str, segmenters: dict, out_dir: Path, seed: int) -> list[str]:
    """Scan ``scene_id`` and write the cache and pixel files of every segmenter in
    ``segmenters`` ({name: Segmenter}) that has none yet. Returns the names recorded."""
    from calnav.mapping.voxel_map import SemanticVoxelMap

    todo = [n for n in segmenters if not all(p.exists() for p in scene_files(out_dir, n, scene_id))]
    if not todo:
        return []
    src = frame_source(cfg, scene_id, seed)
    rng = np.random.default_rng([seed, 1])
    map_cfg = dataclasses.replace(cfg.mapping, fusion="rbu", weighting="none", glfs_params="")
    names = src.class_names
    k = len(names)
    for name in todo:
        seg = segmenters[name]
        if tuple(seg.class_names) != tuple(names):
            raise ValueError(f"segmenter {name} predicts classes {seg.class_names}, the scene {scene_id} has {names}")
        cache = ObsCache(k, map_cfg.voxel_size_m, cap=cfg.study.cache_cap, seed=seed, class_names=names)
        vmap = SemanticVoxelMap(k, map_cfg, class_names=names, obs_cache=cache)
        pix_logits, pix_labels = [], []
        for rgb, depth, sem, poses in src.batches(SEGMENT_BATCH):
            logits = seg.segment_batch(rgb, depth, semantic=sem, poses=poses)
            for f, lg in enumerate(logits):
                vmap.integrate(depth[f], src.intrinsics, poses[f], lg)
                valid = np.flatnonzero(sem[f].ravel() >= 0)
                if len(valid):
                    pick = rng.choice(valid, min(cfg.study.pixels_per_frame, len(valid)), replace=False)
                    pix_logits.append(lg.reshape(-1, k)[pick])
                    pix_labels.append(sem[f].ravel()[pick])
        if len(cache) == 0:
            raise ValueError(f"scan of {scene_id} observed no voxel (empty observation cache)")
        if not pix_labels:
            raise ValueError(f"{scene_id} has no labelled pixels (no semantic frames) for 2D scaling and pixel mECE")
        src.label(cache)
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
    """One house to record on a backend worker: the study config (validated where it was loaded:
    it pickles to the worker as it is), the house, the segmenters still missing its files, and
    the scan seed."""

    cfg: Config
    scene_id: str
    segmenters: tuple[str, ...]
    seed: int


_segmenter_cache: dict = {}   # per worker process: (name, device) -> Segmenter, built once


def record_task(task: RecordTask) -> dict[str, bytes]:
    """Record one house in a temporary directory on whichever worker runs it and return its
    files as {path relative to the study directory: bytes}, so the driver writes them and
    workers on other nodes need no shared disk."""
    import tempfile

    from calnav.agent.segmenters import make_segmenter

    cfg = task.cfg
    segs = {}
    for name in task.segmenters:
        key = (name, cfg.run.device)
        if key not in _segmenter_cache:
            _segmenter_cache[key] = make_segmenter(name, cfg.segmenter, device=cfg.run.device)
        segs[name] = _segmenter_cache[key]
    with tempfile.TemporaryDirectory(prefix="calnav-record-") as tmp:
        record_scene(cfg, task.scene_id, segs, Path(tmp), task.seed)
        return {str(p.relative_to(tmp)): p.read_bytes() for name in task.segmenters
                for p in scene_files(Path(tmp), name, task.scene_id)}


def record_houses(cfg: Config, scene_seeds: dict[str, int], segmenters: tuple[str, ...],
                  out_dir: Path, progress: bool = True) -> None:
    """Record every house of ``scene_seeds`` ({scene id: scan seed}) that lacks a segmenter's
    files, as tasks on the ``run.backend`` backend (houses are the slow stage); each house's
    files are written as it arrives (pixels first, the cache last: its presence marks the
    house done), so a killed study resumes."""
    from calnav.eval.runner import raise_failures, run_tasks

    tasks = []
    for sid, seed in scene_seeds.items():
        missing = tuple(n for n in segmenters if not all(p.exists() for p in scene_files(out_dir, n, sid)))
        if missing:
            tasks.append(RecordTask(cfg, sid, missing, seed))

    def save(_, files: dict[str, bytes]) -> None:
        for rel in sorted(files, key=lambda r: r.endswith(".cache.npz")):  # the cache last
            dest = out_dir / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(dest, files[rel])

    failures = run_tasks(record_task, tasks, cfg.run, save=save, desc="record scans", unit="house",
                         total=len(scene_seeds), progress=progress)
    raise_failures(failures, "house", name=lambda task: task.scene_id)
