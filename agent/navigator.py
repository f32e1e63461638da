"""The ObjectNav agent as a library: ``Navigator``, the one entry point a robot program imports.

    from calnav.agent.config import AgentConfig
    from calnav.agent.navigator import Navigator
    from calnav.agent.setup import AgentSetup, SensorSetup

    nav = Navigator(AgentSetup(agent=AgentConfig(segmenter="learned_rgb"),
                               sensor=SensorSetup(resolution=(640, 480), hfov_deg=79.0, camera_height_m=0.88)))
    nav.reset("chair")
    while True:
        decision = nav.act(rgb, depth, pose=camera_pose)   # or gps=..., compass=...
        if decision.action == Action.STOP:
            break
        robot.do(decision.action)   # or drive to decision.short_term_goal / long_term_goal

The Navigator is how every calnav command that runs episodes runs the agent: ``calnav
objectnav`` (its workers drive a Navigator through the episode loop, ``eval.rollout``, as an
``EpisodeAgent``), ``calnav habitat-benchmark`` (``agent.habitat_agent.HabitatAgent`` wraps
one), ``calnav view-episode``, ``calnav collect-maps`` and ``calnav replay`` (``calnav bench``
times the agent's stages and ``calnav start-pose`` steps several agents in lockstep: both
drive the registry agent itself). It builds the agent ``setup.name`` with ``agent.setup.build_agent`` from its
typed setup (``agent.setup.AgentSetup``: the agent, segmenter and mapping sections, the sensor's
facts, the device; a command makes it from its config with ``eval.config.agent_setup``); every step is ``observe(obs)`` on a Habitat observation (rgb,
depth, gps, compass, objectgoal; ``semantic`` and the privileged keys when an env gives them),
which ``act`` builds from a robot's inputs (the goal's id, gps and compass from a pose). It
turns the agent's step (``agent.step.Step``) into metres (``Decision``, which carries the step
for the episode loop's hooks); the map is read and saved with ``map`` /
``save_map`` (``agent.navigator_map.AgentMap``).

Inputs of ``act`` (shapes, units): ``rgb`` (H, W, 3) uint8; ``depth`` (H, W) or (H, W, 1)
float32 at the same size, metres (0 = invalid), or Habitat's normalised [0, 1] depth when
``sensor.normalize_depth`` is true; (H, W) must be ``sensor.resolution`` and the camera a pinhole
of ``sensor.hfov_deg`` with its principal point at the image centre, level (no pitch, no roll), at
``sensor.camera_height_m`` above the floor -- the agent's sensor model (``agent.sensors``;
``env.*`` of the same names in a calnav config).

The pose, one of:

- ``gps`` (2,) (forward, right) metres and ``compass`` (1,) radians, counter-clockwise: Habitat's
  EpisodicGPS / EpisodicCompass sensors, relative to the episode's first step;
- ``pose``: a (4, 4) world-from-camera transform (OpenCV camera axes: x right, y down, z
  forward; any fixed world frame with +z up, e.g. a ROS ``map`` / ``odom`` frame), or (3,)
  (x, y, yaw) of the camera in such a frame (metres; yaw radians counter-clockwise from +x).
  It is turned into gps / compass relative to the pose given at the first ``act`` after
  ``reset`` (``StartFrame``, Habitat's own computation, ``envs.task.xy_yaw_to_gps_compass``).
  A (4, 4) pose tilted more than ``LEVEL_TOLERANCE_DEG`` from level is refused.

Outputs are in the episode-start frame (``envs.task``): origin at the camera's position at the
first step, on the floor; +x forward at that step, +y to its left, +z up; metres.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

from calnav.agent.navigator_map import AgentMap
from calnav.agent.sensors import check_depth, check_resolution
from calnav.agent.segmenters.base import task_goal_categories
from calnav.agent.setup import AgentSetup, build_agent
# planar_pose, StartFrame and LEVEL_TOLERANCE_DEG are the library's too (``calnav.agent.navigator``)
from calnav.agent.start_frame import ANGLE_SLACK, LEVEL_TOLERANCE_DEG, StartFrame, planar_pose  # noqa: F401
from calnav.agent.step import Step
from calnav.envs.task import (COMPASS, DEPTH, GPS, OBJECTGOAL, RGB, SEMANTIC, Action, gps_compass_to_xy_yaw,
                              require_keys)

# What a robot's inputs cannot be beside the pose (``agent.start_frame``) and depth
# (``agent.sensors.check_depth``):
# - motion: a step moves 0.25 m; 50 m between two steps is no robot's, but a pose in millimetres.
MAX_STEP_JUMP_M = 50.0


@dataclass(frozen=True)
class GoalSighting:
    """The goal component the agent heads for on its map: ``accepted`` (it passed
    ``agent.goal_threshold``; False: a candidate in [agent.uncertain_low, goal_threshold) it
    goes to verify), its highest map confidence ``peak`` in [0, 1], ``area_m2`` and its centre
    (x, y) metres."""

    accepted: bool
    peak: float
    area_m2: float
    centre: tuple[float, float]


@dataclass(frozen=True)
class Decision:
    """One step of the agent. ``action``: Habitat's discrete action (``envs.task.Action``: STOP,
    MOVE_FORWARD, TURN_LEFT, TURN_RIGHT); ``mode``: why ('spin': the opening turn, 'explore',
    'goal': heading for a detected goal, 'verify', 'look' (a second look before STOP), 'untrap': escaping, 'stop': STOP at the goal or the step limit);
    ``step``: 1 at the first ``act`` after ``reset``. In the episode-start frame (module
    docstring), metres: ``position`` (x, y) and ``yaw`` (rad) of the agent as it read them;
    ``long_term_goal`` (x, y): the frontier / predicted goal it explores toward, or the goal
    cell nearest it when heading for a detection (None when it has none); ``short_term_goal``
    (x, y): the point its planner steers to now, ``agent.ring_cells`` away (None when it turns
    in place); ``goal``: the goal component it heads for, or None; ``agent_step``: the agent's
    own step it was read from (``agent.step.Step``: map state, step info, frame), what the
    episode loop's hooks draw."""

    action: Action
    mode: str
    step: int
    position: tuple[float, float]
    yaw: float
    long_term_goal: tuple[float, float] | None
    short_term_goal: tuple[float, float] | None
    goal: GoalSighting | None
    agent_step: Step = field(compare=False, repr=False)   # (the map it holds is no value to compare)


class Navigator:
    """The agent of ``setup`` (an ``agent.setup.AgentSetup``) as a library (module docstring).
    ``reset(goal)`` starts a search; ``act(rgb, depth, pose=... | gps=..., compass=...)`` returns
    a ``Decision``; ``map()`` / ``save_map(path)`` read and save the map at any time.
    ``simulator``: an env's privileged handle (``envs.task.SimulatorHandle``), for an agent that
    declares it (the oracle)."""

    def __init__(self, setup: AgentSetup, *, simulator=None):
        self.setup = setup
        self.agent_name = setup.name
        self.agent = build_agent(setup, simulator=simulator)
        self.goal_categories = task_goal_categories(setup.agent)   # what objectgoal ids index (the task's contract)
        self._goal_id: int | None = None           # reset's goal; None: the first observation's
        self._start: StartFrame | None = None
        self._last_gps: np.ndarray | None = None   # the last act's gps (float64 m): the motion check
        self._reset = self._started = False
        self._steps = 0
        self._last: Step | None = None   # the agent's last step: its map and frame

    @property
    def goal(self) -> str | None:
        """The goal category searched since the last ``reset`` (None before one, or before the
        first observation when ``reset`` left it to the observations)."""
        return None if self._goal_id is None else self.goal_categories[self._goal_id]

    @property
    def needs_semantic(self) -> bool:
        """Whether ``act`` needs ``semantic=``: the segmenter reads a simulator's semantic sensor
        (``gt``, ``noisy``)."""
        return bool(self.agent.needs_semantic)

    @property
    def goal_names(self) -> tuple[str, ...]:
        """The goal categories ``reset`` accepts: calnav's ObjectNav goals that the agent can find."""
        return self.agent.goal_names()

    def goal_id(self, goal: str | int) -> int:
        """The task's ``objectgoal`` id of ``goal`` (a name of ``goal_names``, or its id in
        ``agent.segmenters.base.task_goal_categories``); ValueError naming the valid goals."""
        names, categories = self.goal_names, self.goal_categories
        if isinstance(goal, (int, np.integer)) and not isinstance(goal, (bool, np.bool_)):
            if 0 <= int(goal) < len(categories) and categories[int(goal)] in names:
                return int(goal)
        elif isinstance(goal, str) and goal in names:
            return categories.index(goal)
        valid = ", ".join(f"{n} ({categories.index(n)})" for n in names)
        raise ValueError(f"unknown goal {goal!r}; valid: {valid}")

    def reset(self, goal: str | int | None = None) -> None:
        """Start a new search for ``goal`` (name or id; None: the ``objectgoal`` of the first
        observation, Habitat's way): the next ``act`` / ``observe`` is the episode's first step
        (its pose defines the start frame; the map starts empty)."""
        self._goal_id = None if goal is None else self.goal_id(goal)
        self._start, self._reset, self._started, self._steps = None, True, False, 0
        self._last_gps: np.ndarray | None = None
        self._last = None

    def act(self, rgb: np.ndarray, depth: np.ndarray, *, gps=None, compass=None, pose=None,
            semantic: np.ndarray | None = None) -> Decision:
        """The agent's step on one frame (module docstring for the inputs). ``semantic``: (H, W)
        int class ids, -1 void, for the ``gt`` / ``noisy`` segmenters (a simulator's semantic
        sensor). The Habitat observation these make is checked whole (``_check``) before
        anything changes: a refused call leaves the navigator as it was."""
        if self._goal_id is None:
            raise ValueError("call reset(goal) before act()")
        start, gps, compass = self._gps_compass(gps, compass, pose)
        obs = {RGB: rgb, DEPTH: depth, GPS: gps, COMPASS: compass, OBJECTGOAL: np.array([self._goal_id], np.int64)}
        if semantic is not None:
            obs[SEMANTIC] = semantic
        self._check(obs)
        decision = self._step(obs)
        self._start = start   # the first pose's frame, once its step is taken
        return decision

    def begin(self, obs: Mapping) -> None:
        """Start the episode on its first observation now (``observe`` does it on the first call
        after ``reset``): the agent resets on it, as the episode loop resets an agent. The
        observation is checked whole first (``_check``)."""
        self._check(obs)
        self._begin(obs)

    def observe(self, obs: Mapping) -> Decision:
        """The agent's step on a Habitat observation ``obs`` (``envs.task.HABITAT_KEYS``: rgb (H, W, 3)
        uint8, depth (H, W, 1) or (H, W), gps (2,), compass (1,), objectgoal (1,); ``semantic`` and
        the privileged keys an env adds go to the parts that declare them, ``agent.contract``),
        checked whole as ``act`` checks its inputs (``_check``) before anything changes. The
        first call after ``reset`` starts the episode on it (``begin``)."""
        self._check(obs)
        return self._step(obs)

    def _check(self, obs: Mapping) -> None:
        """The one check of a step's input (``act``, ``observe``, ``begin``), before any state
        changes; ValueError (one line): rgb (H, W, 3) uint8; depth (H, W) or (H, W, 1) at its
        size, ``env.resolution``, float metres (``check_depth``); ``semantic`` when the segmenter
        reads it; gps (2,) finite metres, compass one finite angle in
        [-pi, pi] (not degrees); no jump over ``MAX_STEP_JUMP_M`` from the last step taken; on
        the episode's first observation, a goal (``_first_goal``)."""
        require_keys(obs, (RGB, DEPTH, GPS, COMPASS), "Navigator.observe")
        rgb, depth = np.asarray(obs[RGB]), np.asarray(obs[DEPTH])
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"rgb must be (H, W, 3) uint8; got {rgb.dtype} of shape {rgb.shape}")
        if depth.shape[:2] != rgb.shape[:2] or depth.ndim not in (2, 3) or depth.shape[2:] not in ((), (1,)):
            raise ValueError(f"depth must be (H, W) or (H, W, 1) at the rgb's size {rgb.shape[1]}x{rgb.shape[0]}; "
                             f"got shape {depth.shape}")
        check_resolution(depth.shape[:2], self.setup.sensor.resolution)
        check_depth(depth, self.setup.sensor.normalize_depth)
        if self.needs_semantic:
            require_keys(obs, (SEMANTIC,), f"the {self.agent.perception.segmenter.name!r} segmenter")
        gps, compass = np.asarray(obs[GPS]), np.asarray(obs[COMPASS])
        if gps.shape != (2,) or compass.size != 1 or not all(a.dtype.kind in "fiu" for a in (gps, compass)) or \
                not (np.isfinite(gps).all() and np.isfinite(compass).all()):
            raise ValueError(f"gps must be 2 finite numbers (forward, right) and compass one; got {gps.tolist()}, "
                             f"{compass.tolist()}")
        if abs(float(compass.reshape(-1)[0])) > math.pi + ANGLE_SLACK:
            raise ValueError(f"compass {float(compass.reshape(-1)[0]):g} is not Habitat's EpisodicCompass, radians in "
                             "[-pi, pi]: degrees?")
        if self._started and self._last_gps is not None:
            jump = float(np.hypot(*(gps.astype(np.float64) - self._last_gps)))
            if jump > MAX_STEP_JUMP_M:
                raise ValueError(f"the camera moved {jump:.4g} m between steps {self._steps} and {self._steps + 1} "
                                 f"(more than {MAX_STEP_JUMP_M:g} m; a step is env.forward_step_m): poses in "
                                 "millimetres? give metres")
        if not self._started:
            self._first_goal(obs)

    def _first_goal(self, obs: Mapping) -> int:
        """The goal id of the episode's first observation ``obs``: its ``objectgoal``, or
        ``reset``'s goal; ValueError before a ``reset``, without a goal, or for another goal."""
        if not self._reset:
            raise ValueError("call reset() before the episode's first observation")
        goal = int(np.asarray(obs[OBJECTGOAL]).reshape(-1)[0]) if OBJECTGOAL in obs else self._goal_id
        if goal is None:
            raise ValueError("no goal: give reset(goal) or an observation with objectgoal")
        if self._goal_id is not None and goal != self._goal_id:
            raise ValueError(f"the observation's objectgoal {goal} is not reset's goal {self._goal_id}")
        return self.goal_id(goal)

    def _begin(self, obs: Mapping) -> None:
        """The episode started on its (checked) first observation: the agent resets on it."""
        goal = self._first_goal(obs)
        self.agent.reset(obs if OBJECTGOAL in obs else {**obs, OBJECTGOAL: np.array([goal], np.int64)})
        self._goal_id, self._started = goal, True

    def _step(self, obs: Mapping) -> Decision:
        """The agent's step on a checked observation (``_check``)."""
        if not self._started:
            self._begin(obs)
        step = self._last = self.agent.act(obs)
        self._steps += 1
        self._last_gps = np.asarray(obs[GPS], np.float64)   # only a step taken is the next one's reference
        return self._decision(step, obs)

    def _gps_compass(self, gps, compass, pose) -> tuple[StartFrame | None, np.ndarray, np.ndarray]:
        """(start frame, gps (2,), compass (1,)) of ``act``'s pose arguments, changing no state:
        from ``pose`` relative to the start frame (the first pose after ``reset`` makes it;
        ``act`` keeps it once its step is taken), else ``gps`` / ``compass`` (``_check``ed)."""
        if pose is not None:
            if gps is not None or compass is not None:
                raise ValueError("give either pose or gps and compass, not both")
            xy, yaw = planar_pose(pose)
            start = self._start if self._start is not None else StartFrame(xy, yaw)
            return start, *start.gps_compass(xy, yaw)
        if gps is None or compass is None:
            raise ValueError("act() needs the agent's pose: pose=(4, 4) or (x, y, yaw), or gps=(2,) and compass=(1,)")
        return self._start, np.asarray(gps, np.float32), np.asarray(compass, np.float32).reshape(-1)

    # ------------------------------------------------------------------ reading the step
    def _decision(self, step: Step, obs: dict) -> Decision:
        xy, yaw = gps_compass_to_xy_yaw(obs[GPS], obs[COMPASS])
        info = step.info   # a map-less agent (the oracle) tells only its action
        ltg = stg = goal = None
        if info is not None:
            state, cell_m = step.state, step.cell_m
            # the step's cells are in its planning window's coordinates, or the map's without one
            off = (info.window[0].start, info.window[1].start) if info.window is not None else (0, 0)

            def point(rc) -> tuple[float, float]:
                x, y = state.to_world(rc[0] + off[0], rc[1] + off[1], cell_m)
                return float(x), float(y)

            ltg = point(info.long_term_goal) if info.long_term_goal is not None else None
            if info.plan is not None and info.plan.short_term_goal is not None:
                stg = point(info.plan.short_term_goal)
            det = info.detection
            if det is not None and det.area > 0:
                centre = point(np.argwhere(det.mask).mean(axis=0))
                goal = GoalSighting(info.mode != "verify", float(det.peak), det.area * cell_m ** 2, centre)
        mode = info.mode if info is not None else ""
        return Decision(Action(int(step.action)), mode, self._steps, (float(xy[0]), float(xy[1])), float(yaw),
                        ltg, stg, goal, step)

    @property
    def start_frame(self) -> StartFrame | None:
        """The episode-start frame in the world of the poses given to ``act`` (None before the
        first ``act`` after ``reset``, or when the pose is given as gps / compass)."""
        return self._start

    @property
    def frame(self):
        """The last frame the agent mapped (``mapping.frame.SegmentedFrame`` at
        ``agent.map_resolution``: depth (h, w) m, logits (h, w, K), rgb), or None."""
        return None if self._last is None else self._last.frame

    @property
    def class_names(self) -> tuple[str, ...]:
        """The map's classes (the segmenter's), K; none for a map-less agent."""
        return tuple(self.agent.class_names)

    # ------------------------------------------------------------------ the map
    def map(self) -> AgentMap:
        """A copy of the explored part of the 2D map and of the 3D voxel map
        (``agent.navigator_map.AgentMap``); ValueError before the first ``act``."""
        if not self.class_names:
            raise ValueError(f"agent {self.agent_name!r} keeps no map; run.agent=peanut does")
        step = self._last
        if not self._started or step is None:
            raise ValueError("the agent has no map yet: call reset(goal) and act() first")
        return AgentMap.of_state(step.state, step.cell_m, step.class_names, self.setup.mapping.voxel_size_m,
                                 step.goal_name, step.steps, self.setup.agent.map_type)

    def save_map(self, path: str | Path) -> Path:
        """``map()`` written to ``path`` (``AgentMap.save``: a ``calnav map`` map file plus the 2D map)."""
        return self.map().save(path)


class EpisodeAgent:
    """A Navigator as the episode loop's agent (``agent.contract.Agent``, ``eval.rollout``), on
    its public calls only: ``reset(obs)`` is ``navigator.reset()`` and ``begin(obs)`` (a search
    for ``obs``'s objectgoal), ``act(obs)`` the ``agent.step.Step`` of ``navigator.observe(obs)``,
    which the loop's hooks read. This is how ``calnav objectnav`` runs the agent."""

    def __init__(self, navigator: Navigator):
        self.navigator = navigator

    @property
    def class_names(self) -> tuple[str, ...]:
        return self.navigator.class_names

    def reset(self, obs: Mapping) -> None:
        self.navigator.reset()
        self.navigator.begin(obs)

    def act(self, obs: Mapping) -> Step:
        return self.navigator.observe(obs).agent_step
