"""``PeanutAgent``: a PEANUT-like ObjectNav agent on a (calibrated, fused) semantic map.

Per step: segment (``agent.perception``) -> fuse into the 3D map + project to the 2D map
(``agent.semantic_map``) -> collision check (``agent.collision``) -> goal detection
(``agent.goal_detection``) -> when no goal, frontier exploration (``agent.exploration``) or
PEANUT's target prediction (``agent.prediction``, ``agent.exploration: prediction``) ->
local planning (``agent.planner``). The agent reads only Habitat's ObjectNav observations
(``envs.task.HABITAT_KEYS``: rgb, depth, gps, compass, objectgoal; plus ``semantic`` for the
``gt`` / ``noisy`` segmenters, which are built from it) and the task's sensor facts from its
config (``agent.sensors``); its maps live in the episode-start frame. It never touches the
simulator and no decision reads the privileged ``camera_pose`` / ``camera_intrinsics``.

Each episode starts with a full turn in place (360 / turn angle TURN_LEFTs: free for SPL,
which counts path length only) so the first frontier choice sees all around.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from calnav.agent.collision import CollisionTracker, collision_points, is_collision
from calnav.agent.config import AgentConfig
from calnav.agent.exploration import choose_frontier, prior_mask
from calnav.agent.goal_detection import GoalDetection, detect_goal
from calnav.agent.perception import Perception
from calnav.agent.planner import Plan, Planner, heading_to
from calnav.agent.projection import cell_of, dilate
from calnav.agent.semantic_map import MapChannels, MapState, SemanticMapModule
from calnav.agent.sensors import SensorModel
from calnav.envs.task import OBJECTGOAL, Action

PLAN_MARGIN_M = 1.0  # the planning window: explored bounding box + this margin (unknown = optimistic), metres


@dataclass
class StepInfo:
    """What the agent decided and why (for visualisation): mode is one of 'spin', 'untrap' (the escape),
    'goal', 'verify', 'explore', 'stop'. detection / plan / long_term_goal are in window
    coordinates (``window`` = (row slice, col slice) of the map), frontiers in map coordinates."""

    mode: str
    detection: GoalDetection | None
    plan: Plan | None
    long_term_goal: tuple[int, int] | None
    frontiers: np.ndarray | None
    window: tuple[slice, slice] | None = None


class PeanutAgent:
    """``PeanutAgent(cfg, device)``: cfg provides ``.agent`` (AgentConfig), ``.mapping``
    (MappingConfig) and from ``.env`` the task facts max_episode_steps, turn_angle_deg and the
    sensor's resolution, hfov_deg, camera_height_m, min/max_depth_m, normalize_depth (not
    simulator state). ``reset(obs)``, ``act(obs) -> int``; obs holds Habitat's keys."""

    def __init__(self, cfg, device: str = "cpu"):
        self.cfg: AgentConfig = cfg.agent
        self.max_steps = int(cfg.env.max_episode_steps)
        self.spin_turns = int(round(360.0 / cfg.env.turn_angle_deg))
        self.sensors = SensorModel.from_env_config(cfg.env)
        self.perception = Perception(self.cfg, self.sensors, device)
        self.class_names = self.perception.class_names   # class names and ids come from the segmenter
        self.num_classes = len(self.class_names)
        self.map_module = SemanticMapModule(self.cfg, cfg.mapping, self.class_names,
                                            (self.sensors.min_depth_m, self.sensors.max_depth_m))
        self.planner = Planner(self.cfg)
        self.collisions = CollisionTracker(self.cfg)
        self.predictor = None
        if self.cfg.exploration == "prediction":   # PEANUT's target prediction chooses the long-term goals
            from calnav.agent.prediction import DEFAULT_PREDICTOR, Predictor, check_predictor

            path = self.cfg.predictor_weights or DEFAULT_PREDICTOR
            check_predictor(path, self.class_names, self.goal_names(), self.cfg.cell_m)
            self.predictor = Predictor(path)
        self.state: MapState | None = None
        self.info: StepInfo | None = None
        self.pose: np.ndarray | None = None

    # ------------------------------------------------------------------ episode
    def reset(self, obs: dict) -> None:
        self.sensors.check(obs)
        xy, _ = self.sensors.xy_yaw(obs)
        self.goal_id = int(np.asarray(obs[OBJECTGOAL]).reshape(-1)[0])
        self.goal_name = self.class_names[self.goal_id]
        self.state = self.map_module.new_state(xy)
        self.collisions.reset()
        self.steps = 0
        self.last_action: int | None = None
        self.prev_xy = xy.copy()
        self.ltg: tuple[int, int] | None = None
        self.ltg_age = 0
        self.ltg_predicted = False   # the long-term goal came from the prediction (an unexplored cell)
        self.left_ltg: tuple[int, int] | None = None   # the predicted goal given up for the current one
        self.frontiers: np.ndarray | None = None
        self.excluded = np.zeros((self.state.size,) * 2, bool)  # unreachable frontier cells
        self.rejected = np.zeros_like(self.excluded)             # goal candidates verified as wrong
        self.deferred = np.zeros_like(self.excluded)             # goal components the agent looped near
        self.deferred_until = 0                                  # ... ignored until this step
        self.info = None
        self.frame = None
        self.path: list[tuple[int, int]] = []
        self.window: tuple[slice, slice] | None = None
        self.recent: deque[np.ndarray] = deque(maxlen=self.cfg.stuck_steps)   # positions for the watchdog
        self.loop: deque[np.ndarray] = deque(maxlen=self.cfg.loop_steps)      # ... and for the loop check

    def act(self, obs: dict) -> int:
        self.sensors.check(obs)
        xy, yaw = self.sensors.xy_yaw(obs)
        pose = self.pose = self.sensors.pose(obs)   # the camera pose this step maps with (start frame)
        if self.last_action is not None:
            collided = is_collision(self.prev_xy, xy, self.last_action, self.cfg.collision_min_move_m)
            if collided:
                self._mark_collision(xy, yaw)
            routines = self.collisions.routines
            self.collisions.observe(collided)
            self._watch_progress(xy)
            if self.collisions.routines > routines and self.ltg is not None:
                self._exclude_around(self.ltg)  # stuck on the way to this frontier: give it up
        frame = self.frame = self.perception.observe(obs)
        self.map_module.update(self.state, frame, pose)
        self.steps += 1
        self.path.append(self.state.to_cell(xy, self.cfg.cell_m))
        if self.steps >= self.max_steps:
            action, self.info = int(Action.STOP), StepInfo("stop", None, None, None, None)
        else:
            action = self._decide(xy, yaw)
        self.last_action, self.prev_xy = action, xy
        self.collisions.record(action)
        return action

    def _watch_progress(self, xy: np.ndarray) -> None:
        """The no-progress watchdog, after the opening spin: if every position of the last
        ``stuck_steps`` steps lies within ``stuck_radius_m`` of this one, whatever the agent is
        doing is not working (a planner alternating between two blocked headings): escape. If
        every position of the last ``loop_steps`` lies within ``loop_radius_m``, the agent is
        going round in circles: escape, give up the long-term goal and defer the goal component
        it was heading for (``loop_steps`` steps). Both are bounded: the agent never repeats
        the same thing for more than ``loop_steps`` steps."""
        if self.steps < self.spin_turns:
            return
        self.recent.append(xy.copy())
        self.loop.append(xy.copy())
        if self.collisions.escaping:
            return
        if len(self.recent) == self.recent.maxlen and max(math.dist(p, xy) for p in self.recent) < self.cfg.stuck_radius_m:
            self.collisions.force()
            self.recent.clear()
        elif len(self.loop) == self.loop.maxlen and max(math.dist(p, xy) for p in self.loop) < self.cfg.loop_radius_m:
            # moving, but round in circles: the goal (or frontier) it keeps heading for cannot be
            # reached the way the map suggests (a hole in a wall, a gap the simulator blocks).
            # Leave it for loop_steps and explore: other views usually reveal the real way.
            if self.info is not None and self.info.detection is not None and self.info.window is not None \
                    and self.info.mode in ("goal", "verify"):
                self.deferred[:] = False
                self.deferred[self.info.window] |= self.info.detection.mask
                self.deferred_until = self.steps + self.cfg.loop_steps
            if self.ltg is not None:
                self._exclude_around(self.ltg)
                self.ltg = None
            self.collisions.force()
            self.loop.clear()
            self.recent.clear()

    # ------------------------------------------------------------------ decisions
    def _mark_collision(self, xy: np.ndarray, yaw: float) -> None:
        cells, inside = cell_of(collision_points(xy, yaw, self.cfg), self.state.origin, self.cfg.cell_m,
                                   self.state.size)
        self.state.channels[MapChannels.COLLISION].reshape(-1)[cells[inside]] = True

    def _decide(self, xy: np.ndarray, yaw: float) -> int:
        """Everything below works on the window of the explored area (+ PLAN_MARGIN_M), so the
        cost follows the explored area, not the map size."""
        cfg, st = self.cfg, self.state
        if self.steps <= self.spin_turns:
            self.info = StepInfo("spin", None, None, None, None)
            return int(Action.TURN_LEFT)
        untrap = self.collisions.next_action()
        if untrap is not None:
            self.info = StepInfo("untrap", None, None, self.ltg, self.frontiers)
            return untrap
        win = self.window = st.window(int(PLAN_MARGIN_M / cfg.cell_m))
        r, c = st.to_cell(xy, cfg.cell_m)
        agent_rc = (r - win[0].start, c - win[1].start)
        conf = st.semantic[self.goal_id][win]
        rejected = self.rejected[win]
        if self.steps < self.deferred_until:
            rejected = rejected | self.deferred[win]
        det = detect_goal(conf, cfg.goal_threshold, cfg.goal_min_area_cells, exclude=rejected)
        free = ~dilate(st.obstacles(win), cfg.dilation_cells)  # unknown cells are optimistic
        if det.found:
            action = self._approach(det, agent_rc, yaw, free, "goal")
            if action is not None:
                return action
        elif cfg.uncertainty_aware:
            cand = detect_goal(conf, cfg.uncertain_low, cfg.goal_min_area_cells, exclude=rejected)
            if cand.found:
                action = self._approach(cand, agent_rc, yaw, free, "verify")
                if action is not None:
                    return action
        return self._explore(agent_rc, yaw, free, det)

    def _approach(self, det: GoalDetection, agent_rc, yaw: float, free: np.ndarray, mode: str) -> int | None:
        """Go to a detected component; STOP (mode 'goal') or reject it (mode 'verify': still
        uncertain once within verify_distance_m) when close and facing. None if unreachable.
        All cells are in window coordinates."""
        cfg = self.cfg
        cells = np.argwhere(det.mask)
        d = np.hypot(*(cells - agent_rc).T) * cfg.cell_m
        nearest = tuple(int(v) for v in cells[int(np.argmin(d))])
        close = cfg.stop_distance_m if mode == "goal" else cfg.verify_distance_m
        if d.min() <= close:
            ang = heading_to(agent_rc, nearest, yaw)
            if abs(ang) > self.planner.turn_rad:
                self.info = StepInfo(mode, det, None, nearest, self.frontiers, self.window)
                return int(Action.TURN_LEFT if ang > 0 else Action.TURN_RIGHT)
            if mode == "goal":
                self.info = StepInfo("stop", det, None, nearest, self.frontiers, self.window)
                return int(Action.STOP)
            self.rejected[self.window] |= det.mask  # re-observed up close and still below the threshold
            return None
        plan = self.planner.plan(free, det.mask, agent_rc, yaw)
        self.info = StepInfo(mode, det, plan, nearest, self.frontiers, self.window)
        return plan.action if plan.reachable else None

    def _explore(self, agent_rc, yaw: float, free: np.ndarray, det: GoalDetection) -> int:
        """Plan to the long-term frontier goal (kept in map coordinates in ``self.ltg``)."""
        cfg, win = self.cfg, self.window
        self.ltg_age += 1
        local = None if self.ltg is None else (self.ltg[0] - win[0].start, self.ltg[1] - win[1].start)
        reached = local is not None and math.dist(local, agent_rc) <= cfg.ring_cells
        if reached:  # a frontier still open once reached cannot be seen past (e.g. too close for depth)
            self._exclude_around(self.ltg)
        # a predicted goal is worth walking to only while unseen: once its cell is explored the
        # prediction there is void (its value would be 0), so re-choose instead of walking on
        seen = (cfg.prediction_replan_seen and self.ltg_predicted and local is not None
                and bool(self.state.channels[MapChannels.EXPLORED][self.ltg]))
        if local is None or reached or seen or self.ltg_age >= cfg.replan_steps:
            # a periodic re-choice may keep the current goal (PEANUT's rule against flip-flopping)
            local = self._choose_ltg(agent_rc, free, current=None if (reached or seen) else local)
        for _ in range(2):  # one retry with a new frontier if the current one is unreachable
            if local is None:
                break
            goal = np.zeros_like(free)
            goal[local] = True
            plan = self.planner.plan(free, goal, agent_rc, yaw)
            if plan.reachable:
                self.info = StepInfo("explore", det, plan, local, self.frontiers, win)
                return plan.action
            self._exclude_around(self.ltg)
            local = self._choose_ltg(agent_rc, free)
        # Nothing reachable to explore: collision marks (or frontiers judged unreachable) may be
        # blocking a doorway, so forget them and look around; the next step re-plans.
        self.state.channels[MapChannels.COLLISION] = False
        self.excluded[:] = False
        self.ltg = None
        self.info = StepInfo("explore", det, None, None, self.frontiers, win)
        return int(Action.TURN_LEFT)

    def _exclude_around(self, rc: tuple[int, int]) -> None:
        """Never choose frontier cells within goal_dilation_m of map cell ``rc`` again."""
        rad = int(self.cfg.goal_dilation_m / self.cfg.cell_m)
        self.excluded[max(0, rc[0] - rad):rc[0] + rad + 1, max(0, rc[1] - rad):rc[1] + rad + 1] = True

    def goal_names(self) -> tuple[str, ...]:
        """The goal categories the agent may be asked for: the segmenter's classes that are
        ObjectNav goals (the task's ``objectgoal`` ids index the segmenter's classes)."""
        from calnav.agent.segmenters.base import goal_categories

        return tuple(g for g in goal_categories() if g in self.class_names)

    def _predicted_ltg(self, agent_rc, free: np.ndarray) -> tuple[int, int] | None:
        """PEANUT's long-term goal (window coordinates): the most valuable reachable unexplored
        cell of the goal's predicted probability (``agent.prediction``); None when the
        prediction offers nothing (the frontier choice then decides)."""
        from calnav.agent.planner import geodesic_distance
        from calnav.agent.prediction import near_explored, predicted_goal

        st, cfg, win = self.state, self.cfg, self.window
        ch = st.channels
        maps = {"obstacle": st.obstacles(), "explored": ch[MapChannels.EXPLORED], "visited": ch[MapChannels.VISITED]}
        r, c = agent_rc[0] + win[0].start, agent_rc[1] + win[1].start
        prob, corner = self.predictor.probabilities(maps, st.semantic, (r, c), cfg.cell_m, self.goal_name,
                                                    region=st.window(0))
        source = np.zeros_like(free)
        source[agent_rc] = True
        explored = ch[MapChannels.EXPLORED][win]
        near = near_explored(explored, int(round(self.predictor.spec.near_m / cfg.cell_m)))
        candidates = free & ~explored & near & ~self.excluded[win]
        choice = predicted_goal(prob, corner, win, geodesic_distance(free, source), candidates,
                                cfg.prediction_distance_m, cfg.cell_m)
        return None if choice is None else choice[0]

    def _choose_ltg(self, agent_rc, free: np.ndarray, current: tuple[int, int] | None = None
                    ) -> tuple[int, int] | None:
        """Choose a long-term goal (window coordinates in and out): the predicted one with
        ``exploration: prediction`` when the prediction offers one, else a frontier; remembers
        it in map coordinates. ``current``: the goal being walked to when it is still valid
        (a periodic re-choice): a predicted goal is then kept if the new one is the goal it
        replaced (PEANUT's agent: two goals of near-equal value otherwise alternate at every
        re-choice, the agent walking back and forth between them)."""
        st, cfg, win = self.state, self.cfg, self.window
        if self.predictor is not None:
            goal = self._predicted_ltg(agent_rc, free)
            if goal is not None:
                new = (goal[0] + win[0].start, goal[1] + win[1].start)
                rad = int(cfg.goal_dilation_m / cfg.cell_m)   # goals this close share a goal region
                if cfg.prediction_no_switch_back and current is not None and self.ltg_predicted \
                        and _near(new, self.left_ltg, rad):
                    self.ltg_age = 0
                    return current
                if not (self.ltg_predicted and _near(new, self.ltg, rad)):   # a new goal, not the same one moved
                    self.left_ltg = self.ltg if self.ltg_predicted else None
                self.ltg_age, self.ltg_predicted, self.ltg = 0, True, new
                return goal
        prior = prior_mask(st.semantic[:, win[0], win[1]], self.goal_name, self.class_names, cfg)
        choice = choose_frontier(st.channels[MapChannels.EXPLORED][win], st.traversable(cfg, win), agent_rc, cfg,
                                 prior=prior, exclude=self.excluded[win])
        self.ltg_age, self.ltg_predicted = 0, False
        if choice is None:
            self.ltg = self.frontiers = None
            return None
        self.frontiers = np.zeros_like(self.excluded)
        self.frontiers[win] = choice.frontiers
        self.ltg = (choice.goal[0] + win[0].start, choice.goal[1] + win[1].start)
        return choice.goal


def _near(a: tuple[int, int], b: tuple[int, int] | None, cells: int) -> bool:
    """Map cells a and b within ``cells`` of each other along both axes (False without b)."""
    return b is not None and max(abs(a[0] - b[0]), abs(a[1] - b[1])) <= cells
