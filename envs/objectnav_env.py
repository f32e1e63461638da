"""The gymnasium ObjectNav environment (``calnav/ObjectNav-v0``), Habitat's task spec.

Observations (a Dict space): ``rgb`` (H,W,3) uint8; ``depth`` (H,W,1) float32 metres (0 =
invalid); ``semantic`` (H,W) int16 ground-truth class ids (-1 void; omitted when
``semantic_sensor`` is off); ``gps`` (2,) float32 (forward, right) metres relative to the start
pose; ``compass`` (1,) float32 radians relative to the start heading (ccw positive);
``objectgoal`` (1,) int64 goal category id; ``camera_pose`` (4,4) float64 world-from-camera
(OpenCV axes); ``camera_intrinsics`` (3,3) float64.

``info`` carries habitat-lab's metrics at every step: ``distance_to_goal``, ``success``,
``spl``, ``softspl`` (plus ``episode_id``, ``steps``, ``collisions``, ``path_length``).
An episode terminates on STOP and is truncated after ``max_episode_steps`` actions (the
agent, like PEANUT, should STOP on its last step to have a chance of success).

Reward (for RL users; the metrics do not depend on it): habitat-lab's ObjectNav shaping,
reduction in DistanceToGoal, -0.01 per step, +2.5 on success.
"""
from __future__ import annotations

import math
from dataclasses import replace

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from envs.config import EnvConfig
from envs.episodes import ObjectNavEpisode, goal_mask, load_split
from envs.measures import TaskState, objectnav_measurements
from envs.motion import apply_action
from envs.semantics import GOAL_CATEGORIES, NUM_CLASSES
from envs.task import Action, check_action, num_actions

SLACK_REWARD = -0.01
SUCCESS_REWARD = 2.5


class ObjectNavEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, split: str = "val", config: EnvConfig | None = None,
                 episodes: list[ObjectNavEpisode] | None = None, render_mode: str | None = None,
                 **overrides):
        """split: train | val | test. config: an EnvConfig (defaults if None). overrides:
        EnvConfig fields to replace, e.g. ``resolution=(160, 120)``. episodes: run these
        instead of the split's (they must reference loadable scene ids)."""
        cfg = config or EnvConfig()
        if overrides:
            unknown = set(overrides) - set(cfg.__dataclass_fields__)
            if unknown:
                raise ValueError(f"unknown EnvConfig fields {sorted(unknown)}; valid: "
                                 f"{', '.join(cfg.__dataclass_fields__)}")
            cfg = replace(cfg, **overrides)
        cfg = replace(cfg, split=split) if split != cfg.split else cfg
        EnvConfig.__post_init__(cfg)
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode {render_mode!r} not supported; valid: rgb_array")
        self.config = cfg
        self.render_mode = render_mode
        self.episodes = episodes if episodes is not None else load_split(split, cfg)
        if not self.episodes:
            raise ValueError(f"split {split!r} has no episodes")
        self._build_spaces()
        self._scene_id: str | None = None
        self._episode: ObjectNavEpisode | None = None
        self._done = True

    # ----------------------------------------------------------------- spaces
    def _build_spaces(self) -> None:
        from envs.render import Camera

        cfg = self.config
        w, h = cfg.resolution
        self.camera = Camera.from_config(cfg)
        obs = {
            "rgb": spaces.Box(0, 255, (h, w, 3), np.uint8),
            "depth": spaces.Box(0.0, cfg.max_depth_m, (h, w, 1), np.float32),
            "gps": spaces.Box(-np.inf, np.inf, (2,), np.float32),
            "compass": spaces.Box(-np.pi, np.pi, (1,), np.float32),
            "objectgoal": spaces.Box(0, len(GOAL_CATEGORIES) - 1, (1,), np.int64),
            "camera_pose": spaces.Box(-np.inf, np.inf, (4, 4), np.float64),
            "camera_intrinsics": spaces.Box(0.0, np.inf, (3, 3), np.float64),
        }
        if cfg.semantic_sensor:
            obs["semantic"] = spaces.Box(-1, NUM_CLASSES - 1, (h, w), np.int16)
        self.observation_space = spaces.Dict(obs)
        self.action_space = spaces.Discrete(num_actions(cfg.enable_look))

    # ------------------------------------------------------------ scene state
    def _load_scene(self, scene_id: str) -> None:
        if scene_id == self._scene_id:
            return
        from envs.navigation import NavGrid
        from envs.render import Renderer
        from envs.scenes import load_scene

        cfg = self.config
        self.scene = load_scene(scene_id, cfg.dataset)
        self.renderer = Renderer(self.scene, self.camera, min_depth_m=cfg.min_depth_m,
                                 max_depth_m=cfg.max_depth_m, rgb_noise_std=cfg.rgb_noise_std,
                                 depth_noise_std=cfg.depth_noise_std)
        self.navgrid = NavGrid.build(self.scene, cfg, self.renderer.raycasting_scene)
        self._scene_id = scene_id

    @property
    def episode(self) -> ObjectNavEpisode:
        if self._episode is None:
            raise RuntimeError("no episode yet: call reset() first")
        return self._episode

    # ---------------------------------------------------------------- gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """options: {"episode_index": i} or {"episode_id": "scene:idx"}; otherwise an episode
        is drawn with the env's seeded generator."""
        super().reset(seed=seed)
        options = options or {}
        if "episode_index" in options:
            i = int(options["episode_index"])
            if not 0 <= i < len(self.episodes):
                raise ValueError(f"episode_index {i} outside 0:{len(self.episodes)}")
        elif "episode_id" in options:
            ids = [e.episode_id for e in self.episodes]
            if options["episode_id"] not in ids:
                raise ValueError(f"unknown episode_id {options['episode_id']!r}")
            i = ids.index(options["episode_id"])
        else:
            i = int(self.np_random.integers(len(self.episodes)))
        ep = self.episodes[i]
        self._load_scene(ep.scene_id)
        self._episode = ep
        self.goal_field = self.navgrid.geodesic_field(goal_mask(self.navgrid, ep.goals))
        self.position = np.array(ep.start_position, dtype=np.float64)
        self.yaw = float(ep.start_yaw)
        self.pitch = 0.0
        self.steps = 0
        self.collisions = 0
        self._noise_rng = np.random.default_rng(None if seed is None else seed + 1)
        self._task = TaskState(position=self.position.copy(), distance_fn=self.goal_field.distance)
        self._measurements = objectnav_measurements(self.config.success_distance_m)
        self._measurements.reset(self._task)
        self._done = False
        self._last_obs = self._observe()
        return self._last_obs, self._info()

    def step(self, action):
        if self._done:
            raise RuntimeError("the episode is over (STOP or step limit): call reset()")
        a = check_action(action, self.config.enable_look)
        cfg = self.config
        d_before = self._measurements["distance_to_goal"].metric
        self.position, self.yaw, self.pitch, collided = apply_action(self.navgrid, cfg, self.position, self.yaw,
                                                                     self.pitch, a)
        self.collisions += int(collided)
        self.steps += 1
        self._task.position = self.position.copy()
        self._task.stop_called = a == Action.STOP
        self._measurements.update(self._task)
        terminated = a == Action.STOP
        truncated = not terminated and self.steps >= cfg.max_episode_steps
        self._done = terminated or truncated
        m = self._measurements.metrics()
        d_after = m["distance_to_goal"]
        reward = SLACK_REWARD + SUCCESS_REWARD * m["success"]
        if np.isfinite(d_before) and np.isfinite(d_after):
            reward += d_before - d_after
        self._last_obs = self._observe()
        return self._last_obs, float(reward), terminated, truncated, self._info()

    def render(self):
        if self.render_mode == "rgb_array":
            return self._last_obs["rgb"]
        return None

    # ---------------------------------------------------------------- helpers
    def camera_pose(self) -> np.ndarray:
        from envs.render import camera_pose

        return camera_pose(self.position, self.yaw, self.scene.floor_z + self.config.camera_height_m,
                           self.pitch)

    def _observe(self) -> dict:
        pose = self.camera_pose()
        frame = self.renderer.render(pose, rng=self._noise_rng)
        ep = self.episode
        delta = self.position - ep.start_position
        c, s = math.cos(ep.start_yaw), math.sin(ep.start_yaw)
        # habitat-lab's EpisodicGPSSensor: (forward, right) in the start pose's frame
        gps = np.array([c * delta[0] + s * delta[1], s * delta[0] - c * delta[1]], dtype=np.float32)
        compass = (self.yaw - ep.start_yaw + math.pi) % (2 * math.pi) - math.pi
        obs = {
            "rgb": frame.rgb,
            "depth": frame.depth[..., None].astype(np.float32),
            "gps": gps,
            "compass": np.array([compass], dtype=np.float32),
            "objectgoal": np.array([ep.goal_id], dtype=np.int64),
            "camera_pose": pose.astype(np.float64),
            "camera_intrinsics": self.camera.intrinsics.astype(np.float64),
        }
        if self.config.semantic_sensor:
            obs["semantic"] = frame.semantic.astype(np.int16)
        return obs

    def _info(self) -> dict:
        m = self._measurements.metrics()
        return {
            **m, "episode_id": self.episode.episode_id, "steps": self.steps,
            "collisions": self.collisions, "path_length": self._measurements["spl"].path_length,
        }
