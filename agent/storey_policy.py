"""``StoreyPeanutAgent``: the PEANUT-like agent (``agent.policy``) in a house with storeys, what
``run.agent=peanut`` builds when ``env.dataset.storeys > 1`` (``agent.registry.STOREY_AGENTS``).
The floor tracking, the per-storey maps and the stairs are ``agent.storeys``'; here they join
the policy:

- the camera pose of each step is at the tracked floor height + the camera's height, and the
  storey the agent is on is decided before anything is mapped (``_camera_pose``);
- each storey has its own 2-D map, voxel map and frontiers; moving onto another storey swaps
  the map the detector, the selector and the planner work on (their per-map memories start
  afresh there: exclusions, deferrals, collision marks);
- when the current storey has no frontier left the agent takes the stairs: up when it knows
  steps up and no storey above (or it left the storey above longer ago), else down, and it
  commits to the climb until it stands on a floor with no step further, after a look around.
"""
from __future__ import annotations

import numpy as np

from calnav.agent.collision import CollisionMarks
from calnav.agent.goal_detection import GoalDetection, GoalDetector
from calnav.agent.policy import PeanutAgent
from calnav.agent.semantic_map import MapState
from calnav.agent.setup import AgentSetup
from calnav.agent.step import StepInfo
from calnav.agent.storeys import STAIR_MIN_M, STOREY_SWITCH_M, Storey, StoreyMapBuilder
from calnav.agent.watchdog import ProgressWatchdog
from calnav.envs.task import Action, camera_pose


CLIMB_PATIENCE = 60     # actions a climb may take without a step further before it is given up
STOREY_MIN_STEPS = 60   # a storey is explored this many actions after arriving (or a failed climb) before leaving it
# ... and after this many, stairs to a storey not yet seen win over the frontiers left here (the
# step limit is 500: a goal upstairs is not found by exploring every corner downstairs first)
STOREY_EXPLORE_STEPS = 150


class StoreyPeanutAgent(PeanutAgent):
    """``PeanutAgent`` with a map per storey and stairs (module docstring). ``storeys``: the
    storeys met so far (``agent.storeys.Storey``), ``current`` the index of the one it is on,
    ``floor_z`` the height of the floor under it (start frame, metres), ``climb`` +1 / -1 while
    it commits to stairs up / down (0 otherwise)."""

    def __init__(self, setup: AgentSetup):
        super().__init__(setup)
        if self.cfg.map_type != "fused":
            raise ValueError(f"env.dataset.storeys > 1 needs agent.map_type=fused (a voxel map per storey); got "
                             f"{self.cfg.map_type!r}")
        self.mapper = StoreyMapBuilder(self.cfg, setup.mapping, self.class_names,
                                       (self.sensors.min_depth_m, self.sensors.max_depth_m))

    def reset(self, obs) -> None:
        super().reset(obs)
        self.start_xy = self.sensors.xy_yaw(obs)[0].copy()
        self.storeys = [Storey.new(self.state, 0.0, 0)]
        self.current, self.floor_z = 0, 0.0
        self.climb, self.climb_from, self.look_turns, self.climb_steps = 0, 0, 0, 0
        self.climb_after = 0   # no climb starts before this step (just arrived, or a climb just failed)
        self.arrived_at = 0    # the step the agent came onto the current storey
        self.left_at = {0: 0}   # storey -> the step the agent last left it (0: never left)

    # ------------------------------------------------------------------ floor and storey
    def _camera_pose(self, observation, xy: np.ndarray, yaw: float) -> np.ndarray:
        if self.last_action is not None:
            self._track_floor(xy)
        return camera_pose(xy, yaw, self.floor_z + self.sensors.camera_height_m)

    def _track_floor(self, xy: np.ndarray) -> None:
        """The storey the agent is on now, by the floor its last frame registered
        (``_map``)."""
        cfg, st = self.cfg, self.storeys[self.current]
        self.climb_steps += bool(self.climb)
        if st.direction > 0:
            st.z_ref = max(st.z_ref, self.floor_z)
        elif st.direction < 0:
            st.z_ref = min(st.z_ref, self.floor_z)
        away = self.floor_z - st.z_ref
        if abs(away) <= STOREY_SWITCH_M:
            return
        direction = 1 if away > 0 else -1
        ahead = [i for i, s in enumerate(self.storeys) if direction * (s.z_ref - st.z_ref) > 0]
        if ahead:   # a storey it knows: once its floor is nearer than the switch distance (a landing
            # half-way between two storeys belongs to the one the agent was on: no flip-flop)
            near = min(ahead, key=lambda i: abs(self.storeys[i].z_ref - self.floor_z))
            if abs(self.storeys[near].z_ref - self.floor_z) <= STOREY_SWITCH_M:
                self._switch(near)
            return
        state = MapState.empty(self.start_xy, cfg, self.num_classes, self.mapper.new_voxels(),
                               lattice_m=self.mapper.voxel_size_m)
        self.storeys.append(Storey.new(state, self.floor_z, direction).inherit(st, self.floor_z))
        self._switch(len(self.storeys) - 1)

    def _switch(self, index: int) -> None:
        """Stand on storey ``index``: its map is the one every stage works on from now."""
        self.left_at[self.current] = self.steps
        self.current = index
        self.left_at.setdefault(index, 0)
        self.state = self.storeys[index].state
        n = self.state.size
        self.marks = CollisionMarks(self.cfg, n)
        self.detector = GoalDetector(self.cfg, n)
        self.decision.reset(n)   # its evidence is per map
        self.watchdog = ProgressWatchdog(self.cfg, self.detector.deferral)
        self.selector.reset(n, self.goal_name)
        self.look_turns, self.climb_steps = 0, 0
        self.climb_after = self.steps + STOREY_MIN_STEPS
        self.arrived_at = self.steps

    def _map(self, frame, pose: np.ndarray) -> None:
        """Map the frame into the current storey; the mapper registers its height, which is
        the agent's floor from now (``agent.storeys.StoreyMapBuilder.register``)."""
        self.mapper.storey, self.mapper.floor_z = self.storeys[self.current], self.floor_z
        self.mapper.prev_xy = None if self.last_action is None else self.prev_xy
        self.mapper.update(self.state, frame, pose)
        self.floor_z = self.mapper.floor_z

    # ------------------------------------------------------------------ stairs
    def _explore(self, agent_rc, yaw: float, free: np.ndarray, det: GoalDetection) -> int:
        """Explore the storey's own floor (``Storey.off_floor``: not its stairs); take the stairs
        when it has no frontier left (or a storey not seen yet is due); explore toward the
        stairs when the agent knows no flight there yet (it saw their foot only)."""
        self.selector.elsewhere = self.storeys[self.current].off_floor(self.window, self.cfg.cell_m)
        if not self.climb and self.steps - self.arrived_at >= STOREY_EXPLORE_STEPS:
            self._start_climb(free, unvisited_only=True)   # a storey never seen may hold the goal
        if not self.climb:
            goal = self.selector.select(self.state, self.window, agent_rc, free)
            if goal is None and not self._start_climb(free):
                self.selector.elsewhere = None
                goal = self.selector.select(self.state, self.window, agent_rc, free)
            if not self.climb:
                return self._explore_goal(goal, agent_rc, yaw, free, det)
        action = self._climb(agent_rc, yaw, free, det)
        if action is not None:
            return action
        return self._explore_goal(self.selector.select(self.state, self.window, agent_rc, free), agent_rc, yaw, free,
                                  det)

    def _start_climb(self, free: np.ndarray, unvisited_only: bool = False) -> bool:
        """Commit to the stairs it knows (module docstring): when no frontier is left here, or
        (``unvisited_only``) to a storey it has not been on yet; False when it knows none."""
        if self.steps < self.climb_after:
            return False
        st = self.storeys[self.current]

        def last_left(d: int) -> int:   # the storey that way: never visited first, else the longest left
            ahead = [i for i, s in enumerate(self.storeys) if d * (s.z_ref - st.z_ref) > 0]
            return -1 if not ahead else self.left_at.get(min(ahead, key=lambda i: abs(self.storeys[i].z_ref - st.z_ref)), 0)

        options = [d for d in (1, -1) if st.flights(free, self.window, d, self.cfg.cell_m).any()
                   and (not unvisited_only or last_left(d) < 0)]
        if not options:
            return False

        self.climb, self.climb_from, self.look_turns = min(options, key=last_left), self.current, 0
        self.climb_steps, self.climb_z, self.climb_best = 0, self.floor_z, 0.0
        return True

    def _climb(self, agent_rc, yaw: float, free: np.ndarray, det: GoalDetection) -> int | None:
        """The committed climb's action: toward the next step, or a look around when it sees
        none; None when it is over (on a new storey's floor with no step further, or after a
        full look around with no step known)."""
        st = self.storeys[self.current]
        progress = self.climb * (self.floor_z - self.climb_z)
        if progress > self.climb_best + STAIR_MIN_M:
            self.climb_best, self.climb_steps = progress, 0
        if self.climb_steps >= CLIMB_PATIENCE:
            return self._end_climb()   # no step further in all that time: no (more) stairs there
        steps = st.next_steps(free, self.window, self.floor_z, self.climb, any_lower=True)
        if steps.any():
            plan = self.planner.plan(free, steps, agent_rc, yaw, dilate_goal=False)
            if plan.reachable:
                self.look_turns = 0
                self.info = StepInfo("stairs", det, plan, None, self.selector.frontiers, self.window)
                return plan.action
        if self.look_turns < self.spin_turns:   # a landing hides the next flight until the agent turns
            self.look_turns += 1
            self.info = StepInfo("stairs", det, None, None, self.selector.frontiers, self.window)
            return int(Action.TURN_LEFT)
        return self._end_climb()

    def _end_climb(self) -> None:
        """The climb is over: back to exploring (a climb that left no storey waits
        ``STOREY_MIN_STEPS`` before the next)."""
        if self.current == self.climb_from:
            self.climb_after = self.steps + STOREY_MIN_STEPS
        self.climb, self.look_turns = 0, 0
        return None
