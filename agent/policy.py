"""``PeanutAgent`` (``run.agent=peanut``): a PEANUT-like ObjectNav agent on a (calibrated,
fused) semantic map, composed of one part per stage. This file only composes them:

| stage | part | file |
|---|---|---|
| perceive | ``Perception``: subsample, segment | ``agent.perception`` |
| map | the map builder of ``agent.map_type`` (``agent.registry.MAP_BUILDERS``); collision marks | ``agent.semantic_map``, ``agent.collision`` |
| detect | ``GoalDetector``: accept, verify / reject, defer | ``agent.goal_detection`` |
| decide | the STOP decision of ``agent.decision`` (``agent.registry.DECISIONS``): STOP on arrival, or an uncertainty test over views first | ``agent.evidence`` |
| select | the goal selector of ``agent.exploration`` (``agent.registry.GOAL_SELECTORS``) | ``agent.goal_selection`` |
| plan | ``Planner``: geodesic field, short-term goal | ``agent.planner`` |
| act | the opening spin; the approach to a goal and its STOP (``GoalApproach``); the escape (``CollisionTracker``) on blocks or the watchdog's word (``ProgressWatchdog``) | ``agent.approach``, ``agent.collision``, ``agent.watchdog`` |

The agent reads only Habitat's ObjectNav observations: it splits the env's observation at
its boundary (``agent.contract.split_observation``); every stage reads the ``Observation``
(rgb, depth, gps, compass, objectgoal, and ``semantic`` for the ``gt`` / ``noisy``
segmenters), and the privileged part goes to perception alone, which hands the segmenter what
its class declares. The task's sensor facts come from its config (``agent.sensors``); its maps
live in the episode-start frame. It never touches the simulator.

Each episode starts with a full turn in place (360 / turn angle TURN_LEFTs: free for SPL,
which counts path length only) so the first frontier choice sees all around.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from calnav.agent.approach import Approach, GoalApproach
from calnav.agent.collision import CollisionMarks, CollisionTracker, is_collision
from calnav.agent.config import AgentConfig
from calnav.agent.contract import split_observation
from calnav.agent.goal_detection import GoalDetection, GoalDetector
from calnav.agent.perception import Perception
from calnav.agent.planner import Planner
from calnav.agent.projection import dilate
from calnav.agent.registry import DECISIONS, GOAL_SELECTORS, MAP_BUILDERS, STOREY_AGENTS
from calnav.agent.segmenters.base import task_goal_categories
from calnav.agent.setup import AgentSetup
from calnav.agent.step import Step, StepInfo
from calnav.agent.watchdog import LOOP, ProgressWatchdog
from calnav.envs.task import OBJECTGOAL, Action

PLAN_MARGIN_M = 1.0  # the planning window: explored bounding box + this margin (unknown = optimistic), metres
HEADING_MODES = ("goal", "verify", "look")   # steps that head for a detected component (the one a loop defers)


class PeanutAgent:
    """``PeanutAgent(setup)`` (``agent.setup.AgentSetup``: its ``agent``, ``segmenter`` and
    ``mapping`` sections, the task's facts ``sensor`` (not simulator state), on ``device``).
    ``reset(obs)``, ``act(obs) -> Step`` (``agent.contract.Agent``, ``agent.step.Step``: the
    action and what it was decided from); obs holds Habitat's keys."""

    name = "peanut"

    def __init__(self, setup: AgentSetup):
        self.cfg: AgentConfig = setup.agent
        self.max_steps = int(setup.sensor.max_episode_steps)
        self.spin_turns = int(round(360.0 / setup.sensor.turn_angle_deg))
        self.sensors = setup.sensor.model
        self.approach = GoalApproach(self.cfg, setup.sensor)
        self.perception = Perception(self.cfg, setup.segmenter, self.sensors, setup.device)
        self.class_names = self.perception.class_names   # the map's channels: the segmenter's classes
        self.goal_categories = task_goal_categories(self.cfg)   # what objectgoal ids index (the task's contract)
        self.num_classes = len(self.class_names)
        self.mapper = MAP_BUILDERS.get(self.cfg.map_type)(self.cfg, setup.mapping, self.class_names,
                                                          (self.sensors.min_depth_m, self.sensors.max_depth_m))
        self.planner = Planner(self.cfg)
        self.decision = DECISIONS.get(self.cfg.decision)(self.cfg, setup.mapping.temperature)
        self.collisions = CollisionTracker(self.cfg)
        self.selector = GOAL_SELECTORS.get(self.cfg.exploration)(self.cfg, self.class_names, self.goal_names())
        self.predictor = getattr(self.selector, "predictor", None)   # PEANUT's network (exploration: prediction)
        self.state = None
        self.info: StepInfo | None = None
        self.pose: np.ndarray | None = None

    @classmethod
    def from_setup(cls, setup: AgentSetup) -> "PeanutAgent":
        """The registry's builder (``agent.setup.build_agent``); in a house with storeys
        (``sensor.storeys > 1``, a fact of the task like the camera's height) the agent of
        ``agent.registry.STOREY_AGENTS`` (``agent.storey_policy``)."""
        if setup.sensor.storeys > 1:
            return STOREY_AGENTS.get(cls.name)(setup)
        return cls(setup)

    @property
    def needs_semantic(self) -> bool:
        """Whether its segmenter reads a simulator's semantic sensor (``gt``, ``noisy``)."""
        return bool(self.perception.segmenter.needs_semantic)

    def goal_names(self) -> tuple[str, ...]:
        """The goal categories the agent may be asked for: the ObjectNav goals (the task's
        ``objectgoal`` ids index them) that are among the segmenter's classes."""
        return tuple(g for g in self.goal_categories if g in self.class_names)

    # ------------------------------------------------------------------ episode
    def reset(self, obs: Mapping) -> None:
        observation, _ = split_observation(obs)   # a reset reads nothing privileged
        self.sensors.check(observation)
        xy, _ = self.sensors.xy_yaw(observation)
        # the task's objectgoal id indexes calnav's goal categories; the map's channels are the
        # segmenter's classes, matched by name (a segmenter need not list them in calnav's order)
        self.goal_id = int(np.asarray(observation[OBJECTGOAL]).reshape(-1)[0])
        if not 0 <= self.goal_id < len(self.goal_categories):
            raise ValueError(f"objectgoal {self.goal_id} is not a goal category id; valid: 0 to "
                             f"{len(self.goal_categories) - 1} ({', '.join(self.goal_categories)})")
        self.goal_name = self.goal_categories[self.goal_id]
        if self.goal_name not in self.class_names:
            raise ValueError(f"the goal {self.goal_name!r} is not among the segmenter's classes "
                             f"({', '.join(self.class_names)})")
        self.goal_channel = self.class_names.index(self.goal_name)   # its map channel
        self.state = self.mapper.new_state(xy)
        n = self.state.size
        self.collisions.reset()
        self.marks = CollisionMarks(self.cfg, n)
        self.detector = GoalDetector(self.cfg, n)
        self.decision.reset(n)
        self.watchdog = ProgressWatchdog(self.cfg, self.detector.deferral)
        self.selector.reset(n, self.goal_name)
        self.steps = 0
        self.last_action: int | None = None
        self.prev_xy = xy.copy()
        self.collided = False                                    # the last forward was blocked
        self.info = None
        self.frame = None
        self.path: list[tuple[int, int]] = []
        self.window: tuple[slice, slice] | None = None

    def act(self, obs: Mapping) -> Step:
        observation, privileged = split_observation(obs)
        self.sensors.check(observation)
        xy, yaw = self.sensors.xy_yaw(observation)
        pose = self.pose = self._camera_pose(observation, xy, yaw)   # the camera pose this step maps with (start frame)
        if self.last_action is not None:
            self._after_move(xy, yaw)
        frame = self.frame = self.perception.observe(observation, privileged)    # perceive
        self._map(frame, pose)                                                    # map
        self.decision.observe(self.state, frame, pose, self.goal_channel)        # evidence over views
        self.steps += 1
        self.path.append(self.state.to_cell(xy, self.cfg.cell_m))
        if self.steps >= self.max_steps:
            action, self.info = int(Action.STOP), StepInfo("stop", None, None, None, None)
        else:
            action = self._decide(xy, yaw)
        self.last_action, self.prev_xy = action, xy
        self.collisions.record(action)
        return Step(action, self.steps, self.info, self.state, frame, pose, self.path, self.goal_name,
                    self.goal_channel, self.class_names, self.cfg.cell_m)

    def _camera_pose(self, observation, xy: np.ndarray, yaw: float) -> np.ndarray:
        """(4, 4) start-frame-from-camera pose of this step: level, at the camera's height
        above the start's floor (``agent.sensors``; ``agent.storey_policy`` tracks the floor)."""
        return self.sensors.pose(observation)

    def _map(self, frame, pose: np.ndarray) -> None:
        """Map the segmented ``frame`` seen from ``pose`` into the map state."""
        self.mapper.update(self.state, frame, pose)

    def _after_move(self, xy: np.ndarray, yaw: float) -> None:
        """What the last action did: a blocked forward marks the map and counts toward an escape;
        after the opening spin the watchdog may start one too (and, on a loop, the long-term
        goal is given up and the goal component headed for deferred); an escape that begins
        excludes the long-term goal's frontier."""
        collided = self.collided = is_collision(self.prev_xy, xy, self.last_action, self.cfg.collision_min_move_m)
        if collided:
            self.marks.mark(self.state, xy, yaw)
        routines = self.collisions.routines
        self.collisions.observe(collided)
        if self.steps >= self.spin_turns:
            event = self.watchdog.observe(xy, self.collisions.escaping)
            if event == LOOP:
                info = self.info
                if info is not None and info.detection is not None and info.window is not None \
                        and info.mode in HEADING_MODES:
                    here = self.state.to_cell(xy, self.cfg.cell_m)
                    self.detector.defer_heading(info.detection.mask, info.window, here, self.approach.blocked_reach_cells)
                self.selector.give_up()
            if event is not None:
                self.collisions.force()
        if self.collisions.routines > routines:
            self.selector.exclude_goal()   # stuck on the way to this frontier: give it up

    # ------------------------------------------------------------------ decisions
    def _decide(self, xy: np.ndarray, yaw: float) -> int:
        """Everything below works on the window of the explored area (+ PLAN_MARGIN_M), so the
        cost follows the explored area, not the map size."""
        cfg, st = self.cfg, self.state
        if self.steps <= self.spin_turns:
            self.info = StepInfo("spin", None, None, None, None)
            return int(Action.TURN_LEFT)
        untrap = self.collisions.next_action()
        if untrap is not None:
            self.info = StepInfo("untrap", None, None, self.selector.goal, self.selector.frontiers)
            return untrap
        win = self.window = st.window(int(PLAN_MARGIN_M / cfg.cell_m))
        r, c = st.to_cell(xy, cfg.cell_m)
        agent_rc = (r - win[0].start, c - win[1].start)
        det, candidate = self.detector.detect(st.semantic[self.goal_channel][win], win, self.decision)  # detect
        free = ~dilate(st.obstacles(win), cfg.dilation_cells)  # unknown cells are optimistic
        if det.found:
            move = self.approach.next(det.mask, st, win, agent_rc, yaw, free, self.collided)
            move = self.decision.review(move, det, st, self.goal_channel, win, agent_rc, free)        # decide
            if move.mode == "reject":   # the evidence failed after the last look: never this object again
                self.detector.rejected[win] |= det.mask
                return self._explore(agent_rc, yaw, free, det)
            action = self._go(move, det, agent_rc, yaw, free)
            if action is not None:
                return action
            if move.mode == "look":     # its view point cannot be reached: the look is given up
                self.decision.abandon()
        elif candidate is not None:
            action = self._go(self.detector.verify(candidate, agent_rc, yaw, self.planner.turn_rad, win), candidate,
                              agent_rc, yaw, free)
            if action is not None:
                return action
        return self._explore(agent_rc, yaw, free, det)

    def _go(self, move: Approach, det: GoalDetection, agent_rc, yaw: float, free: np.ndarray) -> int | None:
        """Carry out a move toward the detected component ``det``: its action now, or the
        plan to its target (window cells); None when there is none or the plan is unreachable."""
        frontiers = self.selector.frontiers
        if move.action is not None:
            self.info = StepInfo(move.mode, det, None, move.nearest, frontiers, self.window)
            return move.action
        if move.target is None:
            return None
        plan = self.planner.plan(free, move.target, agent_rc, yaw, dilate_goal=move.dilate_goal)     # plan
        self.info = StepInfo(move.mode, det, plan, move.nearest, frontiers, self.window)
        return plan.action if plan.reachable else None

    def _explore(self, agent_rc, yaw: float, free: np.ndarray, det: GoalDetection) -> int:
        """Plan to the long-term goal (window cells), with one more choice if it is unreachable."""
        goal = self.selector.select(self.state, self.window, agent_rc, free)                  # select
        return self._explore_goal(goal, agent_rc, yaw, free, det)

    def _explore_goal(self, goal, agent_rc, yaw: float, free: np.ndarray, det: GoalDetection) -> int:
        """``_explore`` once the long-term goal (window cells, or None) is chosen."""
        st, win = self.state, self.window
        for _ in range(2):
            if goal is None:
                break
            target = np.zeros_like(free)
            target[goal] = True
            plan = self.planner.plan(free, target, agent_rc, yaw)                               # plan
            if plan.reachable:
                self.info = StepInfo("explore", det, plan, goal, self.selector.frontiers, win)
                return plan.action
            goal = self.selector.unreachable(st, win, agent_rc, free)
        # Nothing reachable to explore: collision marks (or frontiers judged unreachable) may be
        # blocking a doorway, so forget them and look around; the next step re-plans.
        self.marks.forget(st)
        self.selector.forget_exclusions()
        self.info = StepInfo("explore", det, None, None, self.selector.frontiers, win)
        return int(Action.TURN_LEFT)
