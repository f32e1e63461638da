"""The no-progress watchdog (state beside the policy that consults it).

After the opening spin, every step's position goes in. ``stuck``: every position of the last
``stuck_steps`` steps lies within ``stuck_radius_m`` of the current one -- whatever the agent is
doing is not working (a planner alternating between two blocked headings): escape. ``loop``:
every position of the last ``loop_steps`` lies within ``loop_radius_m`` -- moving, but round in
circles: escape, give up the long-term goal, and set aside the goal component it was heading
for (a goal seen through a hole in a wall, a gap the simulator blocks), for ``loop_steps``
steps, so other views can reveal the real way.

Three rules keep the set-aside from hiding a goal the agent needs: a component the agent is
already within reach of is never set aside (the policy passes ``within_reach``); the same
component is never set aside twice in a row (the second loop only escapes); and the loop check
starts afresh when a set-aside ends, so it cannot fire again on the very step the goal comes
back (both last ``loop_steps``: before, they ran in lockstep and hid a goal for 337 of 500
steps). Positions are (2,) metres in the agent's start frame; masks (n, n) bool map cells.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from calnav.agent.config import AgentConfig


class ProgressWatchdog:
    """``observe(xy, escaping)`` -> None | "stuck" | "loop"; ``set_aside(mask, within_reach)``;
    ``hidden()`` -> the set-aside mask while it lasts, else None."""

    def __init__(self, cfg: AgentConfig, map_cells: int):
        self.cfg = cfg
        self.recent: deque[np.ndarray] = deque(maxlen=cfg.stuck_steps)
        self.loop: deque[np.ndarray] = deque(maxlen=cfg.loop_steps)
        self.mask = np.zeros((map_cells, map_cells), bool)   # the component set aside
        self.last = np.zeros_like(self.mask)                  # the one set aside before (never twice in a row)
        self.until = 0                                        # set aside while step < until
        self.step = 0

    def observe(self, xy: np.ndarray, escaping: bool) -> str | None:
        """One step's position (called once per step after the spin); the event it triggers."""
        self.step += 1
        if self.until and self.step >= self.until:   # the set-aside ends: the loop check starts afresh
            self.until = 0
            self.mask[:] = False
            self.loop.clear()
        self.recent.append(np.array(xy, dtype=np.float64))
        self.loop.append(np.array(xy, dtype=np.float64))
        if escaping:
            return None
        if len(self.recent) == self.recent.maxlen and _spread(self.recent, xy) < self.cfg.stuck_radius_m:
            self.recent.clear()
            return "stuck"
        if len(self.loop) == self.loop.maxlen and _spread(self.loop, xy) < self.cfg.loop_radius_m:
            self.loop.clear()
            self.recent.clear()
            return "loop"
        return None

    def set_aside(self, component: np.ndarray, within_reach: bool) -> bool:
        """Set ``component`` (n, n) bool aside for loop_steps steps after a loop, unless the agent
        is within reach of it or it is the component set aside last time; whether it was."""
        if within_reach or not component.any() or (component & self.last).any():
            return False
        self.mask[:] = component
        self.last[:] = component
        self.until = self.step + self.cfg.loop_steps
        return True

    def hidden(self) -> np.ndarray | None:
        """The set-aside component's mask while the set-aside lasts, else None."""
        return self.mask if self.until else None


def _spread(points, xy: np.ndarray) -> float:
    return max(math.dist(p, xy) for p in points)
