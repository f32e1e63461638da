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
from dataclasses import dataclass

import numpy as np

from calnav.agent.approach import nearest_cell, view_region
from calnav.agent.collision import CollisionTracker, collision_points, is_collision
from calnav.agent.config import AgentConfig
from calnav.agent.exploration import choose_frontier, prior_mask
from calnav.agent.goal_detection import GoalDetection, detect_goal
from calnav.agent.perception import Perception
from calnav.agent.planner import Plan, Planner, heading_to
from calnav.agent.projection import cell_of, dilate
from calnav.agent.segmenters.base import goal_categories
from calnav.agent.semantic_map import MapChannels, MapState, SemanticMapModule
from calnav.agent.sensors import SensorModel
from calnav.agent.watchdog import ProgressWatchdog
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
        # the task's view points reach view_point_radius_m from the goal: STOP inside that, less
        # the map's error (or less only blocked_stop_margin_m once a step toward it is blocked)
        radius = float(cfg.env.view_point_radius_m)
        if not self.cfg.blocked_stop_margin_m <= self.cfg.stop_margin_m < radius:
            raise ValueError(f"need agent.blocked_stop_margin_m ({self.cfg.blocked_stop_margin_m}) <= "
                             f"agent.stop_margin_m ({self.cfg.stop_margin_m}) < env.view_point_radius_m ({radius})")
        self.reach_cells = (radius - self.cfg.stop_margin_m) / self.cfg.cell_m
        self.blocked_reach_cells = (radius - self.cfg.blocked_stop_margin_m) / self.cfg.cell_m
        self.view_half_rad = math.radians(max(cfg.env.hfov_deg / 2 - self.cfg.stop_view_margin_deg, 1.0))
        self.perception = Perception(self.cfg, self.sensors, device)
        self.class_names = self.perception.class_names   # the map's channels: the segmenter's classes
        self.goal_categories = goal_categories()          # what objectgoal ids index (the task's contract)
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
        # the task's objectgoal id indexes calnav's goal categories; the map's channels are the
        # segmenter's classes, matched by name (a segmenter need not list them in calnav's order)
        self.goal_id = int(np.asarray(obs[OBJECTGOAL]).reshape(-1)[0])
        if not 0 <= self.goal_id < len(self.goal_categories):
            raise ValueError(f"objectgoal {self.goal_id} is not a goal category id; valid: 0 to "
                             f"{len(self.goal_categories) - 1} ({', '.join(self.goal_categories)})")
        self.goal_name = self.goal_categories[self.goal_id]
        if self.goal_name not in self.class_names:
            raise ValueError(f"the goal {self.goal_name!r} is not among the segmenter's classes "
                             f"({', '.join(self.class_names)})")
        self.goal_channel = self.class_names.index(self.goal_name)   # its map channel
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
        self.hits = np.zeros(self.excluded.shape, np.uint8)     # blocked forwards that marked each cell
        self.collided = False                                    # the last forward was blocked
        self.watchdog = ProgressWatchdog(self.cfg, self.state.size)
        self.info = None
        self.frame = None
        self.path: list[tuple[int, int]] = []
        self.window: tuple[slice, slice] | None = None

    def act(self, obs: dict) -> int:
        self.sensors.check(obs)
        xy, yaw = self.sensors.xy_yaw(obs)
        pose = self.pose = self.sensors.pose(obs)   # the camera pose this step maps with (start frame)
        if self.last_action is not None:
            collided = self.collided = is_collision(self.prev_xy, xy, self.last_action, self.cfg.collision_min_move_m)
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
        """After the opening spin, the watchdog (``agent.watchdog``): stuck -> escape; round in
        circles -> escape, give up the long-term goal and set aside the goal component headed
        for (unless the agent is within reach of it)."""
        if self.steps < self.spin_turns:
            return
        event = self.watchdog.observe(xy, self.collisions.escaping)
        if event == "loop":
            info = self.info
            if info is not None and info.detection is not None and info.window is not None \
                    and info.mode in ("goal", "verify"):
                component = np.zeros_like(self.excluded)
                component[info.window] = info.detection.mask
                r, c = self.state.to_cell(xy, self.cfg.cell_m)
                d = np.hypot(*(np.argwhere(component) - (r, c)).T).min() if component.any() else np.inf
                self.watchdog.set_aside(component, within_reach=bool(d <= self.blocked_reach_cells))
            if self.ltg is not None:
                self._exclude_around(self.ltg)
                self.ltg = None
        if event is not None:
            self.collisions.force()

    # ------------------------------------------------------------------ decisions
    def _mark_collision(self, xy: np.ndarray, yaw: float) -> None:
        cells, inside = cell_of(collision_points(xy, yaw, self.cfg), self.state.origin, self.cfg.cell_m,
                                   self.state.size)
        cells = np.unique(cells[inside])
        self.state.channels[MapChannels.COLLISION].reshape(-1)[cells] = True
        hits = self.hits.reshape(-1)
        hits[cells] = np.minimum(hits[cells], 254) + 1

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
        conf = st.semantic[self.goal_channel][win]
        rejected = self.rejected[win]
        hidden = self.watchdog.hidden()
        if hidden is not None:
            rejected = rejected | hidden[win]
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
        """Go to a detected component. Mode 'goal': STOP once inside its view region
        (``agent.approach``: within reach, line of sight) and facing it within the camera's
        view; plan to the region's traversable cells. Mode 'verify': reject the component if it
        is still uncertain once within verify_distance_m and facing it. None if unreachable.
        All cells are in window coordinates."""
        cfg = self.cfg
        if mode == "goal":
            reach = self.blocked_reach_cells if self.collided else self.reach_cells
            region = view_region(det.mask, self.state.channels[MapChannels.VIEW_BLOCK][self.window], reach)
            nearest = nearest_cell(det.mask, agent_rc)[0]
            if region[agent_rc]:
                ang = heading_to(agent_rc, nearest, yaw)
                if abs(ang) > self.view_half_rad:
                    self.info = StepInfo(mode, det, None, nearest, self.frontiers, self.window)
                    return int(Action.TURN_LEFT if ang > 0 else Action.TURN_RIGHT)
                self.info = StepInfo("stop", det, None, nearest, self.frontiers, self.window)
                return int(Action.STOP)
            # aim at floor seen free (not at unseen cells: a scan's floor holes look like those)
            target = region & self.state.traversable(cfg, self.window) & ~det.mask
            if not target.any():
                target = region & free & ~det.mask
            plan = self.planner.plan(free, target if target.any() else det.mask, agent_rc, yaw,
                                     dilate_goal=not target.any())
            self.info = StepInfo(mode, det, plan, nearest, self.frontiers, self.window)
            return plan.action if plan.reachable else None
        nearest, d = nearest_cell(det.mask, agent_rc)
        if d * cfg.cell_m <= cfg.verify_distance_m:
            ang = heading_to(agent_rc, nearest, yaw)
            if abs(ang) > self.planner.turn_rad:
                self.info = StepInfo(mode, det, None, nearest, self.frontiers, self.window)
                return int(Action.TURN_LEFT if ang > 0 else Action.TURN_RIGHT)
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
        self._forget_collisions()
        self.excluded[:] = False
        self.ltg = None
        self.info = StepInfo("explore", det, None, None, self.frontiers, win)
        return int(Action.TURN_LEFT)

    def _forget_collisions(self) -> None:
        """Drop the collision marks, except cells that more than one blocked forward marked: an
        obstacle the agent cannot see (a floor hole, a step) that it would walk into again."""
        self.state.channels[MapChannels.COLLISION] = self.hits >= 2

    def _exclude_around(self, rc: tuple[int, int]) -> None:
        """Never choose frontier cells within goal_dilation_m of map cell ``rc`` again."""
        rad = int(self.cfg.goal_dilation_m / self.cfg.cell_m)
        self.excluded[max(0, rc[0] - rad):rc[0] + rad + 1, max(0, rc[1] - rad):rc[1] + rad + 1] = True

    def goal_names(self) -> tuple[str, ...]:
        """The goal categories the agent may be asked for: the ObjectNav goals (the task's
        ``objectgoal`` ids index them) that are among the segmenter's classes."""
        return tuple(g for g in self.goal_categories if g in self.class_names)

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
