"""The gymnasium ObjectNav environment (``calnav/ObjectNav-v0``), Habitat's task spec.

Observations (a Dict space, the contract ``envs.task.observation_specs``): ``rgb`` (H,W,3)
uint8; ``depth`` (H,W,1) float32 metres (0 = invalid), or Habitat's normalised depth in [0, 1]
with ``normalize_depth``; ``semantic`` (H,W) int16 ground-truth class ids (-1 void; omitted
when ``semantic_sensor`` is off); ``gps`` (2,) float32 (forward, right) metres relative to the
start pose; ``compass`` (1,) float32 radians relative to the start heading (ccw positive);
``objectgoal`` (1,) int64 goal category id; ``camera_pose`` (4,4) float64 world-from-camera
(OpenCV axes) and ``camera_intrinsics`` (3,3) float64: privileged, for debugging and the
simulated segmenters only (Habitat gives neither).

``info`` carries habitat-lab's metrics at every step: ``distance_to_goal``, ``success``,
``spl``, ``softspl`` (plus ``episode_id``, ``steps``, ``collisions``, ``path_length``, and
``start_storey``, ``goal_storey``, ``storey``: the storey the agent started on, the one of the
nearest goal, the one it is on; all 0 in a single-storey house). In a house with storeys
(``env.dataset.storeys``) the agent moves on a ``LayeredNavGrid``: MOVE_FORWARD takes the
stairs, the camera rides the floor under the agent (steps included), DistanceToGoal is the
geodesic through the stairs and the path length L sums 3-D steps (habitat-lab's agent
positions), the climb included.
An episode terminates on STOP and is truncated after ``max_episode_steps`` actions (the
agent, like PEANUT, should STOP on its last step to have a chance of success).
``gym.make(ENV_ID, max_episode_steps=N)`` sets that limit: gymnasium's ``TimeLimit`` is applied
outside the env, so ``EpisodeLimit`` (registered as the id's additional wrapper) hands N to the
env, which then truncates, reports and ends its episode at N too.

Reward (for RL users; the metrics do not depend on it): habitat-lab's ObjectNav shaping,
reduction in DistanceToGoal, -0.01 per step, +2.5 on success.
"""
from __future__ import annotations

from dataclasses import replace

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from calnav.envs.config import EnvConfig
from calnav.envs.episodes import ObjectNavEpisode, goal_mask, load_split
from calnav.envs.measures import TaskState, objectnav_measurements
from calnav.envs.motion import apply_action, apply_layered_action
from calnav.envs.episode_datasets import task_categories
from calnav.envs.semantics import NUM_CLASSES
from calnav.envs.task import (CAMERA_INTRINSICS, CAMERA_POSE, COMPASS, DEPTH, GPS, OBJECTGOAL, RGB, SEMANTIC, Action,
                       SimulatorHandle, check_action, normalize_depth_m, num_actions, observation_specs,
                       xy_yaw_to_gps_compass)

SLACK_REWARD = -0.01
SUCCESS_REWARD = 2.5
RESET_OPTIONS = ("episode_index", "episode_id")  # keys reset(options=...) understands


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
        self.categories = task_categories(cfg)   # what objectgoal ids name (an episode file's, or calnav's)
        self._build_spaces()
        self._scene_id: str | None = None
        self._episode: ObjectNavEpisode | None = None
        self._done = True

    # ----------------------------------------------------------------- spaces
    def _build_spaces(self) -> None:
        from calnav.envs.render import Camera

        cfg = self.config
        w, h = cfg.resolution
        self.camera = Camera.from_config(cfg)
        specs = observation_specs(w, h, len(self.categories), NUM_CLASSES, cfg.max_depth_m, cfg.normalize_depth,
                                  cfg.semantic_sensor)
        self.observation_space = spaces.Dict({k: spaces.Box(s.low, s.high, s.shape, s.dtype) for k, s in specs.items()})
        self.action_space = spaces.Discrete(num_actions(cfg.enable_look))

    # ------------------------------------------------------------ scene state
    def _load_scene(self, scene_id: str, dataset_config: str = "") -> None:
        if scene_id == self._scene_id:
            return
        from calnav.envs.navigation import NavGrid
        from calnav.envs.render import Renderer
        from calnav.envs.scenes import load_scene

        cfg = self.config
        self.scene = load_scene(scene_id, cfg.dataset, dataset_config=dataset_config)
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
        """options: None, {"episode_index": i} (an int in [0, number of episodes)) or
        {"episode_id": "scene:idx"}; without either an episode is drawn with the env's seeded
        generator. Anything else is a ValueError naming the option."""
        super().reset(seed=seed)
        i = self._episode_from_options(options)
        ep = self.episodes[i]
        if ep.refused:
            raise ValueError(f"episode {i} ({ep.episode_id} of {ep.scene_id}) cannot run on calnav's navmesh: "
                             f"{ep.refused}")
        self._load_scene(ep.scene_id, ep.scene_dataset_config)
        self._episode = ep
        self.goal_field = self.navgrid.geodesic_field(goal_mask(self.navgrid, ep.goals))
        self.position = np.array(ep.start_position, dtype=np.float64)
        self.layer = 0   # the storey (the navigation layer) the agent stands on
        if self.navgrid.layered:
            found = self.navgrid.locate(self.position, ep.start_height)
            self.layer = int(ep.start_storey) if found is None else found
        self.yaw = float(ep.start_yaw)
        self.pitch = 0.0
        self.steps = 0
        self.collisions = 0
        self._noise_rng = np.random.default_rng(None if seed is None else seed + 1)
        self._goal_instances = np.array([g.object_id for g in ep.goals], dtype=np.int64)
        self._task = TaskState(position=self._task_position(), distance_fn=self._distance_fn())
        self._measurements = objectnav_measurements(self.config.success_distance_m)
        self._last_obs = self._observe()
        self._measurements.reset(self._task)
        self._done = False
        return self._last_obs, self._info()

    def _episode_from_options(self, options) -> int:
        """Index of the episode ``reset(options=...)`` asks for (see ``reset``)."""
        if options is None:
            options = {}
        if not isinstance(options, dict):
            raise ValueError(f"reset options must be a dict such as {{'episode_index': 0}}, got "
                             f"{type(options).__name__} {options!r}")
        unknown = sorted(set(options) - set(RESET_OPTIONS), key=str)
        if unknown:
            raise ValueError(f"unknown reset option {unknown[0]!r}; valid options: {', '.join(RESET_OPTIONS)}")
        if len(options) > 1:
            raise ValueError("reset options: give either episode_index or episode_id, not both")
        n = len(self.episodes)
        if "episode_index" in options:
            i = options["episode_index"]
            if isinstance(i, (bool, np.bool_)) or not isinstance(i, (int, np.integer)):
                raise ValueError(f"reset option episode_index must be an int in [0, {n}), got {i!r}")
            if not 0 <= i < n:
                raise ValueError(f"reset option episode_index {i} is outside 0:{n} (the split's episodes)")
            return int(i)
        if "episode_id" in options:
            eid = options["episode_id"]
            if not isinstance(eid, str):
                raise ValueError(f"reset option episode_id must be a str like 'scene:000', got {eid!r}")
            ids = [e.episode_id for e in self.episodes]
            if eid not in ids:
                raise ValueError(f"unknown episode_id {eid!r}; ids look like {ids[0]!r}")
            return ids.index(eid)
        runnable = [i for i, e in enumerate(self.episodes) if not e.refused]   # a draw skips refused episodes
        if not runnable:
            raise ValueError(f"every one of the {n} episodes is refused on calnav's navmesh; the first: "
                             f"{self.episodes[0].refused}")
        return runnable[int(self.np_random.integers(len(runnable)))] if len(runnable) < n \
            else int(self.np_random.integers(n))

    def step(self, action):
        if self._done:
            raise RuntimeError("the episode is over (STOP or step limit): call reset()")
        a = check_action(action, self.config.enable_look)
        cfg = self.config
        d_before = self._measurements["distance_to_goal"].metric
        if self.navgrid.layered:
            self.position, self.layer, self.yaw, self.pitch, collided = apply_layered_action(
                self.navgrid, cfg, self.position, self.layer, self.yaw, self.pitch, a)
        else:
            self.position, self.yaw, self.pitch, collided = apply_action(self.navgrid, cfg, self.position, self.yaw,
                                                                         self.pitch, a)
        self.collisions += int(collided)
        self.steps += 1
        self._task.position = self._task_position()
        self._task.stop_called = a == Action.STOP
        self._last_obs = self._observe()
        self._measurements.update(self._task)
        terminated = a == Action.STOP
        truncated = not terminated and self.steps >= cfg.max_episode_steps
        self._done = terminated or truncated
        m = self._measurements.metrics()
        d_after = m["distance_to_goal"]
        reward = SLACK_REWARD + SUCCESS_REWARD * m["success"]
        if np.isfinite(d_before) and np.isfinite(d_after):
            reward += d_before - d_after
        return self._last_obs, float(reward), terminated, truncated, self._info()

    def render(self):
        if self.render_mode == "rgb_array":
            return self._last_obs["rgb"]
        return None

    # ---------------------------------------------------------------- helpers
    def _task_position(self) -> np.ndarray:
        """What the measures read: (2,) xy on one storey; (3,) xy and floor height on a
        layered grid (the climb counts in the path length, as habitat-lab's 3-D positions)."""
        if not self.navgrid.layered:
            return self.position.copy()
        return np.append(self.position, self.navgrid.floor_height(self.position, self.layer))

    def _distance_fn(self):
        """DistanceToGoal of a task position: the goal field at it (on the agent's layer)."""
        if not self.navgrid.layered:
            return self.goal_field.distance
        field = self.goal_field
        return lambda p: field.distance(np.asarray(p)[:2], self.layer)

    def simulator_handle(self) -> SimulatorHandle:
        """Privileged access for an oracle agent (``envs.task.SimulatorHandle``): the
        shortest-path follower on this env's navigation grid, from its true pose to the
        episode's goal field, read afresh at every call (any episode of this env)."""
        from calnav.envs.oracle import FollowerHandle

        return FollowerHandle(lambda: self.navgrid, lambda: self.config, lambda: (self.position, self.yaw),
                              lambda: self.goal_field, layer=lambda: self.layer)

    def camera_pose(self) -> np.ndarray:
        from calnav.envs.render import camera_pose

        # the agent stands on the navmesh, as in habitat-sim: the camera rides the floor under it
        floor = (self.navgrid.floor_height(self.position, self.layer) if self.navgrid.layered
                 else self.navgrid.floor_height(self.position))
        return camera_pose(self.position, self.yaw, floor + self.config.camera_height_m, self.pitch)

    def _observe(self) -> dict:
        pose = self.camera_pose()
        frame = self.renderer.render(pose, rng=self._noise_rng)
        self._task.goal_in_view = bool(np.isin(frame.instance, self._goal_instances).any())
        ep = self.episode
        cfg = self.config
        gps, compass = xy_yaw_to_gps_compass(self.position, self.yaw, ep.start_position, ep.start_rotation)
        depth = frame.depth.astype(np.float32)
        if cfg.normalize_depth:
            depth = normalize_depth_m(depth, cfg.min_depth_m, cfg.max_depth_m)
        obs = {
            RGB: frame.rgb,
            DEPTH: depth[..., None],
            GPS: gps,
            COMPASS: compass,
            OBJECTGOAL: np.array([self.categories.index(ep.object_category)], dtype=np.int64),
            CAMERA_POSE: pose.astype(np.float64),
            CAMERA_INTRINSICS: self.camera.intrinsics.astype(np.float64),
        }
        if cfg.semantic_sensor:
            obs[SEMANTIC] = frame.semantic.astype(np.int16)
        return obs

    def _info(self) -> dict:
        m = self._measurements.metrics()
        return {
            **m, "episode_id": self.episode.episode_id, "steps": self.steps,
            "collisions": self.collisions, "path_length": self._measurements["spl"].path_length,
            "start_storey": int(self.episode.start_storey), "goal_storey": int(self.episode.goal_storey),
            "storey": int(self.layer),
        }


class EpisodeLimit(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Makes the env honour ``gym.make(ENV_ID, max_episode_steps=N)``.

    gymnasium builds the env first and wraps it in ``TimeLimit(N)`` afterwards, so the env would
    keep its config's limit (500) and run on past N if stepped further. This wrapper, which
    gymnasium applies after ``TimeLimit`` (it is the id's registered additional wrapper), finds the
    ``TimeLimit`` and sets the env's ``max_episode_steps`` to N. A config that states another
    limit of its own (not the default) contradicts the argument: refused, naming both."""

    def __init__(self, env: gym.Env):
        gym.utils.RecordConstructorArgs.__init__(self)  # so gym.make(env.spec) can rebuild it
        gym.Wrapper.__init__(self, env)
        limit = _time_limit(env)
        base = env.unwrapped
        if limit is None or not isinstance(base, ObjectNavEnv) or limit == base.config.max_episode_steps:
            return
        if base.config.max_episode_steps != EnvConfig().max_episode_steps:
            raise ValueError(f"gym.make(max_episode_steps={limit}) contradicts the env config's "
                             f"max_episode_steps={base.config.max_episode_steps}: give one of them")
        base.config = replace(base.config, max_episode_steps=limit)
        EnvConfig.__post_init__(base.config)


def _time_limit(env: gym.Env) -> int | None:
    """The step limit of the outermost gymnasium ``TimeLimit`` around ``env``, or None."""
    while isinstance(env, gym.Wrapper):
        if isinstance(env, gym.wrappers.TimeLimit):
            return int(env._max_episode_steps)  # gymnasium keeps it only there
        env = env.env
    return None
