"""Collision handling: detect a blocked forward move, mark the cells ahead as obstacles, and
an untrap routine after repeated blocks.

``collision_cells`` is the pure part (geometry); ``CollisionTracker`` holds the state
(previous position, consecutive blocks, queued untrap actions).
"""
from __future__ import annotations

import numpy as np

from agent.config import AgentConfig
from envs.task import Action


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


class CollisionTracker:
    """Consecutive-collision count and the untrap routine (alternating turn direction:
    turn, turn, forward, forward, ... for ``untrap_steps`` actions)."""

    def __init__(self, cfg: AgentConfig):
        self.cfg = cfg
        self.reset()

    def reset(self) -> None:
        self.consecutive = 0
        self.routines = 0
        self.queue: list[int] = []

    def observe(self, collided: bool) -> None:
        """Record the outcome of the last action; queue an untrap routine when stuck."""
        self.consecutive = self.consecutive + 1 if collided else 0
        if self.consecutive >= self.cfg.untrap_after and not self.queue:
            turn = Action.TURN_LEFT if self.routines % 2 == 0 else Action.TURN_RIGHT
            pattern = [int(turn), int(turn), int(Action.MOVE_FORWARD), int(Action.MOVE_FORWARD)]
            self.queue = [pattern[i % len(pattern)] for i in range(self.cfg.untrap_steps)]
            self.routines += 1
            self.consecutive = 0

    def next_action(self) -> int | None:
        """The next untrap action, or None when no routine is running."""
        return self.queue.pop(0) if self.queue else None
