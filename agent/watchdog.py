"""The no-progress watchdog: it tells the policy when what the agent is doing is not working.

After the opening spin, every step's position goes in (``observe``). ``stuck``: every position
of the last ``stuck_steps`` steps lies within ``stuck_radius_m`` of the current one -- whatever
the agent is doing is not working (a planner alternating between two blocked headings).
``loop``: every position of the last ``loop_steps`` lies within ``loop_radius_m`` -- moving,
but round in circles. The policy answers both with an escape (``agent.collision``) and a loop
also by giving up the long-term goal (``agent.goal_selection``) and deferring the goal
component it was heading for (``agent.goal_detection.Deferral``, whose clock the watchdog
ticks: when a deferral ends, the loop check starts afresh). Positions are (2,) metres in the
agent's start frame.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from calnav.agent.config import AgentConfig
from calnav.agent.goal_detection import Deferral

STUCK, LOOP = "stuck", "loop"   # the events


class ProgressWatchdog:
    """``observe(xy, escaping)`` -> None | STUCK | LOOP, ticking ``deferral``'s clock."""

    def __init__(self, cfg: AgentConfig, deferral: Deferral):
        self.cfg = cfg
        self.deferral = deferral
        self.recent: deque[np.ndarray] = deque(maxlen=cfg.stuck_steps)
        self.loop: deque[np.ndarray] = deque(maxlen=cfg.loop_steps)

    def observe(self, xy: np.ndarray, escaping: bool) -> str | None:
        """One step's position (called once per step after the spin); the event it triggers
        (none while an escape runs)."""
        if self.deferral.tick():   # a set-aside ended: the loop check starts afresh
            self.loop.clear()
        self.recent.append(np.array(xy, dtype=np.float64))
        self.loop.append(np.array(xy, dtype=np.float64))
        if escaping:
            return None
        if len(self.recent) == self.recent.maxlen and _spread(self.recent, xy) < self.cfg.stuck_radius_m:
            self.recent.clear()
            return STUCK
        if len(self.loop) == self.loop.maxlen and _spread(self.loop, xy) < self.cfg.loop_radius_m:
            self.loop.clear()
            self.recent.clear()
            return LOOP
        return None


def _spread(points, xy: np.ndarray) -> float:
    return max(math.dist(p, xy) for p in points)
