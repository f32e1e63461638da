"""Scan a house: the loop at the heart of ``env.dataset.style: scanned``.

    house   = the clean house, lived in: rugs, thresholds, floor clutter (envs.scanning.lived_in)
    poses   = hand-held trajectory through it (envs.trajectories)
    for each pose: render it -> sensor model (noise, dropout, colour) -> TSDF
    mesh    = marching cubes -> floaters dropped -> decimated -> labelled from the lived-in house
    floor   = holes, unlabelled floor patches, a low-frequency warp (envs.scanning.artifacts)

The result is an ordinary ``Scene`` in the clean house's world frame (same rooms, same floor
height), flagged ``meta["lighting"] = "baked"`` (vertex colours already hold the lighting, as in
ScanNet / HM3D meshes, so the renderer does not shade it again). Deterministic per seed.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from calnav.envs.config import EnvConfig
from calnav.envs.navigation import NavGrid
from calnav.envs.render import Camera, Renderer
from calnav.envs.scanning.artifacts import apply_floor_artifacts
from calnav.envs.scanning.config import SCANNER_VERSION, ScanningConfig
from calnav.envs.scanning.lived_in import lived_in
from calnav.envs.scanning.reconstruct import TSDFScan, tidy_mesh, transfer_labels
from calnav.envs.scanning.sensor import camera_rgb, noisy_depth
from calnav.envs.scene import Scene, SceneError, Texture
from calnav.envs.trajectories import TRAJECTORY_VERSION, ScanConfig, scan_poses

BAKED = "baked"   # Scene.meta["lighting"] of meshes whose colours include the lighting
RENDER_RANGE_MARGIN_M = 1.0   # true depth is rendered this far past the sensor's range (noise may pull it in)


def trajectory(scene: Scene, cfg: ScanningConfig, seed: int, env_cfg: EnvConfig | None = None,
               navgrid: NavGrid | None = None) -> np.ndarray:
    """(frames, 4, 4) world-from-camera poses of the hand-held scan of ``scene``."""
    env_cfg = env_cfg or EnvConfig()
    navgrid = navgrid or NavGrid.build(scene, env_cfg)
    walk = ScanConfig(frames=cfg.frames, step_m=cfg.step_m, max_turn_deg=cfg.max_turn_deg,
                      pitch_deg=cfg.pitch_deg, pitch_std_deg=cfg.pitch_std_deg,
                      stop_spacing_m=cfg.stop_spacing_m, extra_turns_mean=cfg.extra_turns_mean, tours=1,
                      up_turn_prob=cfg.up_turn_prob, up_pitch_deg=cfg.up_pitch_deg)
    return scan_poses(scene, navgrid, dataclasses.replace(env_cfg, camera_height_m=cfg.camera_height_m),
                      walk, seed=seed)


def lived_in_house(scene: Scene, cfg: ScanningConfig, seed: int) -> Scene:
    """The clean house ``scene`` as the scan with ``seed`` finds it (``envs.scanning.lived_in``):
    the house the scan's surfaces and labels come from."""
    return lived_in(scene, cfg, np.random.default_rng([seed, SCANNER_VERSION, 1]))


def footprint_m2(scene: Scene) -> float:
    """Area of the scene's xy bounding box, square metres (the density reference)."""
    lo, hi = scene.bounds()
    return float((hi[0] - lo[0]) * (hi[1] - lo[1]))


def scan_house(scene: Scene, cfg: ScanningConfig | None = None, seed: int = 0,
               env_cfg: EnvConfig | None = None, poses: np.ndarray | None = None,
               progress: bool = False) -> Scene:
    """The scanned version of ``scene`` (a clean, labelled ``Scene``).

    cfg: scan settings; seed: seeds the trajectory and every noise draw; env_cfg: the agent's
    settings (the trajectory is planned on its navigation grid); poses: (N, 4, 4) to scan
    along instead of the planned trajectory (tests scan part of a house with it). Raises
    SceneError when the scan observed nothing labelled.
    """
    cfg = cfg or ScanningConfig()
    rng = np.random.default_rng([seed, SCANNER_VERSION])
    house = lived_in_house(scene, cfg, seed)
    if poses is None:
        poses = trajectory(house, cfg, seed, env_cfg)
    w, h = cfg.resolution
    camera = Camera(w, h, cfg.hfov_deg)
    renderer = Renderer(house, camera, 0.0, cfg.max_depth_m + RENDER_RANGE_MARGIN_M)
    k = camera.intrinsics
    tsdf = TSDFScan(cfg)
    frames = poses
    if progress:
        from tqdm import tqdm
        frames = tqdm(poses, desc=f"scanning {scene.name}", unit="frame", leave=False)
    for pose in frames:
        frame = renderer.render(pose, normals=True)
        depth = noisy_depth(frame.depth, frame.rgb, frame.normal, pose, k, cfg, rng)
        tsdf.integrate(depth, camera_rgb(frame.rgb, cfg, rng), k, pose)
    vertices, triangles, colours = tidy_mesh(*tsdf.mesh(), cfg, footprint_m2(scene))
    if len(triangles) == 0:
        raise SceneError(f"scanning {scene.name!r}: the scan observed no surface ({len(poses)} frames)")
    tri_class, tri_instance = transfer_labels(house, vertices, triangles, cfg.label_distance_m,
                                              renderer.raycasting_scene)
    vertices, triangles, tri_class, tri_instance, artifacts = apply_floor_artifacts(
        house, vertices, triangles, tri_class, tri_instance, cfg, np.random.default_rng([seed, SCANNER_VERSION, 2]))
    albedo = np.round(colours[triangles].mean(axis=1) * 255.0)
    meta = {k_: v for k_, v in scene.meta.items() if k_ not in ("generator",)}
    meta.update({"generator": "envs.scanning", "scanner_version": SCANNER_VERSION,
                 "trajectory_version": TRAJECTORY_VERSION, "style": "scanned",
                 "lighting": BAKED, "closed_solids": False, "scan_seed": int(seed), "scan_frames": int(len(poses)),
                 "scanning": cfg.digest_items(), "lived_in": house.meta["lived_in"], "floor_artifacts": artifacts})
    return Scene(name=scene.name, vertices=vertices, triangles=triangles, tri_class=tri_class,
                 tri_instance=tri_instance, tri_albedo=albedo, tri_texture=np.full(len(triangles), Texture.PLAIN),
                 class_names=scene.class_names, rooms=list(scene.rooms), floor_z=scene.floor_z, meta=meta)
