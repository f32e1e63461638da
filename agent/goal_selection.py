"""The select stage: the long-term goal the agent explores toward while no goal is detected,
one selector per ``agent.exploration`` (``agent.registry.GOAL_SELECTORS``):

- ``frontier`` (``FrontierSelector``): the best frontier (``agent.exploration``: size against
  geodesic distance, with the optional co-occurrence prior);
- ``prediction`` (``PredictionSelector``): PEANUT's predicted goal (``agent.prediction``: the
  most valuable reachable unexplored cell), the frontier choice when the prediction offers none.

A selector keeps the episode's long-term goal (``goal``, map cells) and re-chooses it every
``replan_steps`` steps, once it is reached (within ``ring_cells``), when the planner finds it
unreachable (``unreachable``) and, for a predicted goal, once its cell is explored
(``prediction_replan_seen``: the prediction was for an unseen instance). Frontier cells around a
goal given up (reached, unreachable, or abandoned on the watchdog's word: ``give_up``) are
never chosen again (``excluded``) until nothing is left to explore (``forget_exclusions``).
Cells the agent keeps out of exploration for a while (``elsewhere``: the stairs of a storey,
``agent.storey_policy``) are not chosen while they are set.
Goals in and out of ``select`` / ``unreachable`` are (row, col) cells of the planning window
``win``; ``free`` (h, w) bool is its planning map, ``agent_rc`` the agent's window cell.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from calnav.agent.config import AgentConfig
from calnav.agent.exploration import choose_frontier, prior_mask
from calnav.agent.semantic_map import MapChannels, MapState

Cell = tuple[int, int]


class FrontierSelector:
    """``exploration: frontier``. ``class_names``: the map's classes; ``goal_names``: the goal
    categories the agent may be asked for (both from the segmenter)."""

    def __init__(self, cfg: AgentConfig, class_names: Sequence[str], goal_names: Sequence[str]):
        self.cfg = cfg
        self.class_names = tuple(class_names)
        self.goal_names = tuple(goal_names)

    def reset(self, map_cells: int, goal_name: str) -> None:
        """A new episode on an (n, n) map, looking for ``goal_name``."""
        self.goal_name = goal_name
        self.goal: Cell | None = None            # the long-term goal, map cells
        self.age = 0                             # steps since it was chosen
        self.predicted = False                   # it came from the prediction (an unexplored cell)
        self.left: Cell | None = None            # the predicted goal given up for the current one
        self.frontiers: np.ndarray | None = None  # (n, n) bool frontier cells of the last frontier choice
        self.excluded = np.zeros((map_cells, map_cells), bool)   # frontier cells not to choose again
        self.elsewhere: np.ndarray | None = None   # (n, n) bool cells not to choose now (set by the agent)

    # ------------------------------------------------------------------ giving goals up
    def exclude_around(self, rc: Cell) -> None:
        """Never choose frontier cells within goal_dilation_m of map cell ``rc`` again."""
        rad = int(self.cfg.goal_dilation_m / self.cfg.cell_m)
        self.excluded[max(0, rc[0] - rad):rc[0] + rad + 1, max(0, rc[1] - rad):rc[1] + rad + 1] = True

    def exclude_goal(self) -> None:
        """Stuck on the way to the goal (an escape began): its frontier is excluded, the goal kept."""
        if self.goal is not None:
            self.exclude_around(self.goal)

    def give_up(self) -> None:
        """Going round in circles (the watchdog): exclude the goal's frontier and drop the goal."""
        if self.goal is not None:
            self.exclude_around(self.goal)
            self.goal = None

    def forget_exclusions(self) -> None:
        """Nothing reachable to explore: every frontier may be chosen again, from scratch."""
        self.excluded[:] = False
        self.goal = None

    def _excluded(self, win: tuple[slice, slice]) -> np.ndarray:
        """(h, w) bool: the window's cells not to choose (given up, or ``elsewhere``)."""
        return self.excluded[win] if self.elsewhere is None else self.excluded[win] | self.elsewhere[win]

    # ------------------------------------------------------------------ choosing
    def select(self, state: MapState, win: tuple[slice, slice], agent_rc: Cell, free: np.ndarray) -> Cell | None:
        """The goal to plan to this step (window cells), re-chosen when due (module
        docstring); None when there is nothing to explore."""
        cfg = self.cfg
        self.age += 1
        local = None if self.goal is None else (self.goal[0] - win[0].start, self.goal[1] - win[1].start)
        reached = local is not None and math.dist(local, agent_rc) <= cfg.ring_cells
        if reached:  # a frontier still open once reached cannot be seen past (e.g. too close for depth)
            self.exclude_around(self.goal)
        void = local is not None and self._void(state)
        if local is None or reached or void or self.age >= cfg.replan_steps:
            # a periodic re-choice may keep the current goal (PEANUT's rule against flip-flopping)
            local = self._choose(state, win, agent_rc, free, current=None if (reached or void) else local)
        return local

    def unreachable(self, state: MapState, win: tuple[slice, slice], agent_rc: Cell, free: np.ndarray
                    ) -> Cell | None:
        """The planner cannot reach the goal: exclude its frontier and choose another (window
        cells), or None."""
        self.exclude_around(self.goal)
        return self._choose(state, win, agent_rc, free)

    def _void(self, state: MapState) -> bool:
        """Whether the current goal is void before its time (a frontier goal never is)."""
        return False

    def _choose(self, state: MapState, win: tuple[slice, slice], agent_rc: Cell, free: np.ndarray,
                current: Cell | None = None) -> Cell | None:
        """A new long-term goal (window cells; remembered in map cells): the best frontier."""
        return self._choose_frontier(state, win, agent_rc)

    def _choose_frontier(self, state: MapState, win: tuple[slice, slice], agent_rc: Cell) -> Cell | None:
        cfg = self.cfg
        prior = prior_mask(state.semantic[:, win[0], win[1]], self.goal_name, self.class_names, cfg)
        choice = choose_frontier(state.channels[MapChannels.EXPLORED][win], state.traversable(cfg, win), agent_rc,
                                 cfg, prior=prior, exclude=self._excluded(win))
        self.age, self.predicted = 0, False
        if choice is None:
            self.goal = self.frontiers = None
            return None
        self.frontiers = np.zeros_like(self.excluded)
        self.frontiers[win] = choice.frontiers
        self.goal = (choice.goal[0] + win[0].start, choice.goal[1] + win[1].start)
        return choice.goal


class PredictionSelector(FrontierSelector):
    """``exploration: prediction``: PEANUT's target prediction (``agent.prediction``) with the
    network of ``agent.predictor_weights`` (checked against the map's classes, goals and cell)."""

    def __init__(self, cfg: AgentConfig, class_names: Sequence[str], goal_names: Sequence[str]):
        from calnav.agent.prediction import DEFAULT_PREDICTOR, Predictor, check_predictor

        super().__init__(cfg, class_names, goal_names)
        path = cfg.predictor_weights or DEFAULT_PREDICTOR
        check_predictor(path, self.class_names, self.goal_names, cfg.cell_m)
        self.predictor = Predictor(path)

    def _void(self, state: MapState) -> bool:
        """A predicted goal is worth walking to only while unseen: once its cell is explored the
        prediction there is void (its value would be 0), so it is re-chosen (unless
        ``prediction_replan_seen`` is off)."""
        return (self.cfg.prediction_replan_seen and self.predicted
                and bool(state.channels[MapChannels.EXPLORED][self.goal]))

    def _choose(self, state: MapState, win: tuple[slice, slice], agent_rc: Cell, free: np.ndarray,
                current: Cell | None = None) -> Cell | None:
        """The predicted goal when the prediction offers one, else a frontier. ``current``: the
        goal being walked to when it is still valid (a periodic re-choice): a predicted goal is
        then kept if the new one is the goal it replaced (PEANUT's agent: two goals of
        near-equal value otherwise alternate at every re-choice, the agent walking back and
        forth between them)."""
        cfg = self.cfg
        goal = self._predicted(state, win, agent_rc, free)
        if goal is None:
            return self._choose_frontier(state, win, agent_rc)
        new = (goal[0] + win[0].start, goal[1] + win[1].start)
        rad = int(cfg.goal_dilation_m / cfg.cell_m)   # goals this close share a goal region
        if cfg.prediction_no_switch_back and current is not None and self.predicted and _near(new, self.left, rad):
            self.age = 0
            return current
        if not (self.predicted and _near(new, self.goal, rad)):   # a new goal, not the same one moved
            self.left = self.goal if self.predicted else None
        self.age, self.predicted, self.goal = 0, True, new
        return goal

    def _predicted(self, state: MapState, win: tuple[slice, slice], agent_rc: Cell, free: np.ndarray
                   ) -> Cell | None:
        """PEANUT's long-term goal (window cells): the most valuable reachable unexplored cell
        of the goal's predicted probability; None when the prediction offers nothing."""
        from calnav.agent.planner import geodesic_distance
        from calnav.agent.prediction import near_explored, predicted_goal

        cfg, ch = self.cfg, state.channels
        maps = {"obstacle": state.obstacles(), "explored": ch[MapChannels.EXPLORED], "visited": ch[MapChannels.VISITED]}
        r, c = agent_rc[0] + win[0].start, agent_rc[1] + win[1].start
        prob, corner = self.predictor.probabilities(maps, state.semantic, (r, c), cfg.cell_m, self.goal_name,
                                                    region=state.window(0))
        source = np.zeros_like(free)
        source[agent_rc] = True
        explored = ch[MapChannels.EXPLORED][win]
        near = near_explored(explored, int(round(self.predictor.spec.near_m / cfg.cell_m)))
        candidates = free & ~explored & near & ~self._excluded(win)
        choice = predicted_goal(prob, corner, win, geodesic_distance(free, source), candidates,
                                cfg.prediction_distance_m, cfg.cell_m)
        return None if choice is None else choice[0]


def _near(a: Cell, b: Cell | None, cells: int) -> bool:
    """Map cells a and b within ``cells`` of each other along both axes (False without b)."""
    return b is not None and max(abs(a[0] - b[0]), abs(a[1] - b[1])) <= cells
