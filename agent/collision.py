"""Collision handling: detect a blocked forward move, mark the cells ahead as obstacles, and
an escape routine when stuck (repeated blocks, or no progress: ``agent.watchdog``).

``collision_points`` / ``is_collision`` are the pure part (geometry); ``CollisionMarks`` keeps
the marks on the map's ``COLLISION`` channel (and which cells were hit more than once);
``CollisionTracker`` holds the escape's state (blocks since the last move, the running escape).
"""
from __future__ import annotations

import numpy as np

from calnav.agent.config import AgentConfig
from calnav.agent.projection import cell_of
from calnav.agent.semantic_map import MapChannels, MapState
from calnav.envs.task import Action

HITS_MAX = 255   # the hit counter's ceiling (uint8)


def collision_points(xy: np.ndarray, yaw: float, cfg: AgentConfig) -> np.ndarray:
    """World points (M, 2) metres of the strip ahead of an agent at xy (2,) m heading ``yaw``
    rad (counter-clockwise from world +x): from its radius to radius + collision_mark_length_m
    ahead, collision_mark_width_m wide, sampled at half a cell."""
    step = cfg.cell_m / 2
    along = np.arange(cfg.agent_radius_m, cfg.agent_radius_m + cfg.collision_mark_length_m + 1e-9, step)
    half = cfg.collision_mark_width_m / 2
    across = np.arange(-half, half + 1e-9, step)
    a, b = np.meshgrid(along, across)
    fwd = np.array([np.cos(yaw), np.sin(yaw)])
    left = np.array([-fwd[1], fwd[0]])
    return np.asarray(xy, np.float64) + a.reshape(-1, 1) * fwd + b.reshape(-1, 1) * left


def is_collision(prev_xy: np.ndarray, xy: np.ndarray, last_action: int, min_move_m: float) -> bool:
    """A MOVE_FORWARD that travelled less than ``min_move_m`` metres was blocked."""
    return last_action == Action.MOVE_FORWARD and float(np.hypot(*(np.asarray(xy) - prev_xy))) < min_move_m


class CollisionMarks:
    """The obstacle marks of blocked forward moves, on the map's ``COLLISION`` channel, and how
    often each cell was marked (``hits`` (n, n) uint8, per episode)."""

    def __init__(self, cfg: AgentConfig, map_cells: int):
        self.cfg = cfg
        self.hits = np.zeros((map_cells, map_cells), np.uint8)

    def mark(self, state: MapState, xy: np.ndarray, yaw: float) -> None:
        """A forward move from xy (2,) metres heading ``yaw`` rad was blocked: mark the strip ahead."""
        cells, inside = cell_of(collision_points(xy, yaw, self.cfg), state.origin, self.cfg.cell_m, state.size)
        cells = np.unique(cells[inside])
        state.channels[MapChannels.COLLISION].reshape(-1)[cells] = True
        hits = self.hits.reshape(-1)
        hits[cells] = np.minimum(hits[cells], HITS_MAX - 1) + 1

    def forget(self, state: MapState) -> None:
        """Drop the marks, except cells that more than one blocked forward marked: an obstacle
        the agent cannot see (a floor hole, a step) that it would walk into again."""
        state.channels[MapChannels.COLLISION] = self.hits >= 2


class CollisionTracker:
    """Blocked forward moves and the escape routine.

    ``blocked`` counts forward moves blocked since the last one that moved (turns in between do
    not reset it: a planner that turns, hits, turns back and hits again is stuck all the same).
    At ``untrap_after`` blocks, or when the policy reports no progress (``force``), an escape
    starts: turn one step (alternating the direction from one escape to the next), try forward,
    and repeat until a forward step moves -- one more forward then ends it -- or until
    ``untrap_steps`` actions are spent (a full circle of headings takes 2 x 360 / turn angle).
    Every heading tried is either taken or marked blocked by the policy's collision marks, so
    an escape cannot repeat itself.
    """

    def __init__(self, cfg: AgentConfig):
        self.cfg = cfg
        self.reset()

    def reset(self) -> None:
        self.blocked = 0
        self.routines = 0
        self.escaping = False
        self.budget = 0
        self.after_move = False    # the escape's last forward moved: one more forward, then done
        self.last: int | None = None

    def observe(self, collided: bool, moved: bool | None = None) -> None:
        """Record the outcome of the last action (``collided``: a blocked forward; ``moved``: a
        forward that moved, default ``not collided`` for a forward); start an escape when stuck."""
        forward = self.last == Action.MOVE_FORWARD
        moved = (forward and not collided) if moved is None else moved
        if collided:
            self.blocked += 1
        elif moved:
            self.blocked = 0
        if self.escaping and forward:
            if moved and self.after_move:
                self._end()
            else:
                self.after_move = bool(moved)
        if not self.escaping and self.blocked >= self.cfg.untrap_after:
            self.force()

    def force(self) -> None:
        """Start an escape now (the policy saw no progress), unless one is running."""
        if self.escaping:
            return
        self.escaping, self.budget, self.after_move = True, self.cfg.untrap_steps, False
        self.turn = int(Action.TURN_LEFT if self.routines % 2 == 0 else Action.TURN_RIGHT)
        self.routines += 1
        self.blocked = 0

    def _end(self) -> None:
        self.escaping, self.after_move = False, False

    def next_action(self) -> int | None:
        """The escape's next action, or None when no escape is running."""
        if not self.escaping:
            return None
        if self.budget <= 0:
            self._end()
            return None
        self.budget -= 1
        if self.after_move or self.last == self.turn:
            action = int(Action.MOVE_FORWARD)
        else:
            action = self.turn
        return action

    def record(self, action: int) -> None:
        """The action the agent finally took (so the next ``observe`` knows what it was)."""
        self.last = int(action)
