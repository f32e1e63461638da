"""The rules both episode generators share (``envs.episodes`` on one storey,
``envs.storey_episodes`` on a house with storeys; their docstrings state them): how goal view
points are found and the constants of the start draws. Here, so that neither generator imports
the other.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from calnav.envs.config import EnvConfig
from calnav.envs.scene import Scene, sample_surface

TRIVIAL_REJECT_PROB = 0.98        # habitat-lab's rejection rate for near-straight episodes
SURFACE_SAMPLE_SPACING_M = 0.03   # spacing of object surface samples for footprints, metres
VISIBILITY_TARGETS = 48           # object surface points tested for visibility per view point
MAX_START_TRIES = 200             # start-pose draws per episode before giving up
MAX_UNSOLVABLE_TRIES = 10         # ... of which at most this many the oracle cannot solve (each costs a full search)
START_DISTANCE_POWER = 1.0        # start cells are drawn with probability ∝ geodesic^power


# ---------------------------------------------------------------- geometry helpers
def _vertical_half_fov(env_cfg: EnvConfig) -> float:
    w, h = env_cfg.resolution
    return math.atan(math.tan(math.radians(env_cfg.hfov_deg) / 2) * h / w)


def find_view_points(scene: Scene, navgrid, raycasting_scene, instance_id: int, env_cfg: EnvConfig,
                     rng: np.random.Generator) -> np.ndarray:
    """(M, 2) world xy of the view points of one instance (may be empty)."""
    import open3d as o3d

    surface = sample_surface(scene.instance_triangles(instance_id).astype(np.float64),
                             SURFACE_SAMPLE_SPACING_M, rng)
    cells = navgrid.to_cell(surface[:, :2])
    h, w = navgrid.navigable.shape
    inside = (cells[:, 0] >= 0) & (cells[:, 0] < h) & (cells[:, 1] >= 0) & (cells[:, 1] < w)
    footprint = np.zeros((h, w), dtype=bool)
    footprint[cells[inside, 0], cells[inside, 1]] = True
    dist = ndimage.distance_transform_edt(~footprint, sampling=navgrid.cell_m)
    candidates = np.argwhere(navgrid.navigable & (dist <= env_cfg.view_point_radius_m))
    if len(candidates) == 0:
        return np.zeros((0, 2))
    targets = surface[rng.choice(len(surface), size=min(VISIBILITY_TARGETS, len(surface)), replace=False)]
    eyes_xy = navgrid.to_world(candidates)
    feet = scene.floor_z if navgrid.floor_heights is None else navgrid.floor_heights[candidates[:, 0], candidates[:, 1]]
    eyes = np.column_stack([eyes_xy, feet + env_cfg.camera_height_m])   # the camera rides the floor
    direction = targets[None, :, :] - eyes[:, None, :]                       # (C, P, 3)
    length = np.linalg.norm(direction, axis=2)
    elevation = np.arcsin(np.clip(direction[..., 2] / np.maximum(length, 1e-9), -1, 1))
    in_fov = np.abs(elevation) <= _vertical_half_fov(env_cfg)
    rays = np.concatenate([np.repeat(eyes[:, None, :], targets.shape[0], axis=1),
                           direction / np.maximum(length, 1e-9)[..., None]], axis=2)
    hits = raycasting_scene.cast_rays(o3d.core.Tensor(rays.reshape(-1, 6).astype(np.float32)))
    prim = hits["primitive_ids"].numpy().astype(np.int64).reshape(length.shape)
    valid = prim != o3d.t.geometry.RaycastingScene.INVALID_ID
    hit_instance = np.full(prim.shape, -1, dtype=np.int64)
    hit_instance[valid] = scene.tri_instance[prim[valid]]
    visible = ((hit_instance == instance_id) & in_fov).any(axis=1)
    return eyes_xy[visible]
