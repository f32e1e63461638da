"""Frames for training and evaluating segmenters, rendered from a split's procedural houses
(their ``data`` config section: ``eval.sections.SegDataConfig``), and the config loader of
``calnav train-segmenter`` / ``eval-segmenter``.

Poses: short random walks, as an exploring ObjectNav agent moves. Each walk starts at a
uniformly drawn navigable cell with a uniform heading; every step records one frame and then
turns 30 degrees left or right (probability ``turn_prob``) or moves forward 0.25 m (a blocked
move turns instead). The camera sits at ``env.camera_height_m`` (0.88 m) with a small pitch
jitter (Gaussian, ``pitch_jitter_deg``, clipped at 2 sigma). Frames are split evenly over the
split's first ``scenes`` houses (0 = all of them).

Training frames are rebalanced: walls fill ~70 % of random-walk pixels, so a frame whose
object (non-structure) pixels are fewer than ``min_object_fraction`` is kept only with
probability ``keep_sparse_prob`` (the walk goes on either way). Evaluation frames are not
rebalanced: they follow the agent-like walk distribution.

Scans: a share ``scanned_fraction`` of every house's *training* frames is rendered from the
house's scan (``env.dataset.style: scanned``, ``envs.scanning``: holes, lumpy surfaces, baked
and blurred vertex colours, void where the scan kept no label), on walks over the scan's own
navigable cells, so the networks learn reconstructed appearance next to the clean one.
Validation and evaluation frames follow ``env.dataset.style`` alone (score each style with
``env.dataset.style=clean`` / ``scanned``).

Recolouring: a share ``recolour_fraction`` of a house's instances is recoloured and repatterned
in its *training* frames (``eval.segmenter.appearance``), clean and scanned alike (a scan by the
parts of the clean house it was made from), from its own random stream (the poses are those of a
run without it). ``data.eval_appearance: recolour`` recolours every instance of the evaluation
houses the same way.

Frames are rendered without sensor noise (sensor noise and photometric changes are training-time
augmentation, drawn afresh every epoch) and cached at
``cache_dir()/segdata/<split>_<frames>_<key>.npz``, ``key`` a hash of everything that affects
them: rgb (N, H, W, 3) uint8, depth (N, H, W) float16 metres (0 invalid), labels (N, H, W)
int8 class ids (-1 void), poses (N, 4, 4) float32 world-from-camera, scene (N,) int16 index
into the split, and (evaluation sets only) instance (N, H, W) int32.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from calnav.common.atomic import atomic_path
from calnav.envs.config import EnvConfig, plain_dict, require_single_storey
from calnav.envs.scenes import scan_versions
from calnav.envs.semantics import STRUCTURE_CLASSES as STRUCTURE_NAMES
from calnav.eval.sections import SegDataConfig
from calnav.eval.segmenter.appearance import is_baked, recolour_scene

DATA_VERSION = 1                # bump when rendering changes, so stale caches are not reused
EVAL_SEED_OFFSET = 1000         # eval poses use data.seed + this (never the training poses)
VAL_SEED_OFFSET = 500           # per-epoch validation poses likewise
PITCH_CLIP_SIGMA = 2.0          # pitch jitter is clipped at this many standard deviations
MAX_BLOCKED_RETRIES = 12        # a walk whose moves keep failing just records turning frames
RECOLOUR_SCANS_VERSION = 2      # in the cache key of recoloured sets with scans (1 recoloured a scan's
                                # baked colours one triangle at a time)


def segmenter_configs(args) -> list:
    """The config ``calnav train-segmenter`` / ``eval-segmenter`` runs (its sections:
    ``eval.config.SEGMENTER_SECTIONS``)."""
    from calnav.eval.shorthands import load_command_config

    return [load_command_config(args)]


@dataclass
class SegData:
    """Rendered frames (see the module docstring for shapes and dtypes)."""

    rgb: np.ndarray
    depth: np.ndarray
    labels: np.ndarray
    poses: np.ndarray
    scene: np.ndarray
    instance: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.rgb)

    @property
    def resolution(self) -> tuple[int, int]:
        return int(self.rgb.shape[2]), int(self.rgb.shape[1])


# --------------------------------------------------------------------------- rendering
def walk_poses(navgrid, env_cfg: EnvConfig, data_cfg: SegDataConfig, rng: np.random.Generator) -> Iterator[np.ndarray]:
    """Endless (4, 4) world-from-camera poses of consecutive random walks on ``navgrid``."""
    from calnav.envs.render import camera_pose

    turn = np.deg2rad(env_cfg.turn_angle_deg)
    sigma = np.deg2rad(data_cfg.pitch_jitter_deg)
    while True:
        xy = navgrid.sample_navigable(rng, 1)[0]
        yaw = float(rng.uniform(0, 2 * np.pi))
        for _ in range(data_cfg.walk_steps):
            pitch = float(np.clip(rng.normal(0.0, sigma), -PITCH_CLIP_SIGMA * sigma, PITCH_CLIP_SIGMA * sigma)) if sigma > 0 else 0.0
            yield camera_pose(xy, yaw, env_cfg.camera_height_m, pitch)
            if rng.random() < data_cfg.turn_prob:
                yaw += turn if rng.random() < 0.5 else -turn
            else:
                xy, moved = navgrid.move_forward(xy, yaw, env_cfg.forward_step_m)
                if not moved:
                    yaw += turn if rng.random() < 0.5 else -turn


def render_frames(env_cfg: EnvConfig, data_cfg: SegDataConfig, split: str, frames: int, seed: int,
                  with_instance: bool = False, progress: bool = True, rebalance: bool = False,
                  recolour_all: bool = False) -> SegData:
    """Render ``frames`` frames from ``split``'s houses (see the module docstring);
    ``rebalance``: drop most object-sparse frames (training sets); ``recolour_all``: every
    instance recoloured (``data.eval_appearance: recolour``; an un-rebalanced set only)."""
    from tqdm import tqdm

    from calnav.envs.navigation import NavGrid
    from calnav.envs.render import Camera, Renderer
    from calnav.envs.scenes import load_scene, split_scene_ids

    require_single_storey(env_cfg, "rendering segmenter frames")
    ids = split_scene_ids(split, env_cfg.dataset)
    if data_cfg.scenes:
        ids = ids[:data_cfg.scenes]
    if not ids:
        raise ValueError(f"split {split!r} has no scenes (env.dataset.{split}_scenes = 0?)")
    ids = ids[:frames]  # fewer frames than scenes: one frame from each of the first ones
    counts = [frames // len(ids) + (i < frames % len(ids)) for i in range(len(ids))]
    w, h = data_cfg.resolution
    camera = Camera(width=w, height=h, hfov_deg=env_cfg.hfov_deg)
    out = {"rgb": np.empty((frames, h, w, 3), np.uint8), "depth": np.empty((frames, h, w), np.float16),
           "labels": np.empty((frames, h, w), np.int8), "poses": np.empty((frames, 4, 4), np.float32),
           "scene": np.empty(frames, np.int16)}
    if with_instance:
        out["instance"] = np.empty((frames, h, w), np.int32)
    if recolour_all and rebalance:
        raise ValueError("recolour_all is an evaluation shift; training sets use data.recolour_fraction")
    fraction = data_cfg.scanned_fraction if rebalance and env_cfg.dataset.style == "clean" else 0.0
    recolour = data_cfg.recolour_fraction if rebalance else float(recolour_all)
    i = 0
    for s, (scene_id, count) in enumerate(tqdm(list(zip(ids, counts)), desc=f"render {split} frames",
                                               unit="scene", disable=not progress)):
        scanned = int(round(count * fraction))
        # per scene and style: frames do not shift when counts change elsewhere (the clean stream is the
        # one every earlier release drew, so a fraction of 0 renders the same frames as before)
        for style, wanted, rng in ((None, count - scanned, np.random.default_rng([seed, s])),
                                   ("scanned", scanned, np.random.default_rng([seed, s, 1]))):
            if wanted == 0:
                continue
            scene = load_scene(scene_id, env_cfg.dataset, style=style)
            if recolour > 0:   # its own stream: the poses do not move
                source = load_scene(scene_id, env_cfg.dataset, style="clean") if is_baked(scene) else None
                scene = recolour_scene(scene, recolour, np.random.default_rng([seed, s, 2, int(style is None)]),
                                       source=source)
            renderer = Renderer(scene, camera, min_depth_m=env_cfg.min_depth_m, max_depth_m=env_cfg.max_depth_m)
            grid = NavGrid.build(scene, env_cfg, raycasting_scene=renderer.raycasting_scene)
            structure = np.array([n in STRUCTURE_NAMES for n in scene.class_names] + [True])  # last: void
            done = 0
            for pose in walk_poses(grid, env_cfg, data_cfg, rng):
                if done == wanted:
                    break
                fr = renderer.render(pose)
                if rebalance and data_cfg.keep_sparse_prob < 1:
                    objects = float((~structure[fr.semantic]).mean())  # void (-1) indexes the last entry
                    if objects < data_cfg.min_object_fraction and rng.random() >= data_cfg.keep_sparse_prob:
                        continue
                done += 1
                out["rgb"][i], out["depth"][i], out["poses"][i], out["scene"][i] = fr.rgb, fr.depth, pose, s
                sem = fr.semantic
                out["labels"][i] = np.where((sem >= 0) & (sem < len(scene.class_names)), sem, -1)
                if with_instance:
                    out["instance"][i] = fr.instance
                i += 1
    return SegData(**out)


def cache_path(env_cfg: EnvConfig, data_cfg: SegDataConfig, split: str, frames: int, seed: int,
               with_instance: bool, rebalance: bool = False, recolour_all: bool = False) -> Path:
    from calnav.envs.scene import cache_dir

    env_part = {k: getattr(env_cfg, k) for k in ("hfov_deg", "camera_height_m", "min_depth_m", "max_depth_m",
                                                 "turn_angle_deg", "forward_step_m", "agent_radius_m",
                                                 "agent_height_m", "nav_cell_m")}
    data_part = asdict(data_cfg) | {"frames": None, "seed": None}
    if not rebalance:   # the rebalancing knobs, the scan share and recolouring do not change an un-rebalanced set
        data_part |= {"min_object_fraction": None, "keep_sparse_prob": None, "scanned_fraction": None,
                      "recolour_fraction": None}
    for key in ("scanned_fraction", "recolour_fraction"):
        if not data_part.get(key):
            data_part.pop(key)   # keys (and caches) of sets without scans / recolouring are unchanged
    data_part.pop("eval_appearance")   # the camera shift is applied after loading (eval.segmenter.evaluate)
    if data_part.get("recolour_fraction"):
        data_part["recolour_scans"] = RECOLOUR_SCANS_VERSION   # scans recoloured by part and shading
    if recolour_all:
        data_part["recolour_all"] = RECOLOUR_SCANS_VERSION
    if env_cfg.dataset.style == "scanned" or data_part.get("scanned_fraction"):
        data_part["scans"] = scan_versions()   # frames of an older scan are other frames
    blob = json.dumps({"v": DATA_VERSION, "split": split, "frames": frames, "seed": seed, "inst": with_instance,
                       "rebalance": rebalance, "data": data_part,
                       "env": env_part, "dataset": plain_dict(env_cfg.dataset)}, sort_keys=True, default=list)
    key = hashlib.sha1(blob.encode()).hexdigest()[:12]
    return cache_dir() / "segdata" / f"{split}_{frames}_{key}.npz"


def load_or_render(env_cfg: EnvConfig, data_cfg: SegDataConfig, split: str, frames: int | None = None,
                   seed: int | None = None, with_instance: bool = False, progress: bool = True,
                   rebalance: bool = False, recolour_all: bool = False) -> SegData:
    """Cached frames of ``split`` (rendered and saved on first use). frames / seed default to
    ``data_cfg``'s; ``rebalance`` for training sets, ``recolour_all`` (see ``render_frames``)."""
    frames = int(data_cfg.frames if frames is None else frames)
    seed = int(data_cfg.seed if seed is None else seed)
    path = cache_path(env_cfg, data_cfg, split, frames, seed, with_instance, rebalance, recolour_all)
    if path.exists():
        try:
            with np.load(path) as z:
                return SegData(**{k: z[k] for k in z.files})
        except (OSError, ValueError, KeyError, EOFError):
            pass  # a corrupt cache entry: render again
    data = render_frames(env_cfg, data_cfg, split, frames, seed, with_instance, progress, rebalance, recolour_all)
    arrays = {k: v for k, v in asdict_shallow(data).items() if v is not None}
    try:
        with atomic_path(path) as tmp:
            np.savez_compressed(tmp, **arrays)
    except OSError:   # a read-only cache only costs speed
        pass
    return data


def asdict_shallow(data: SegData) -> dict[str, np.ndarray | None]:
    return {k: getattr(data, k) for k in ("rgb", "depth", "labels", "poses", "scene", "instance")}
