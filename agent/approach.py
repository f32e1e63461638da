"""Finishing the approach to a detected goal: where the agent may STOP, and where it plans to.

The task counts a STOP on a *view point*: a navigable spot within the task's view-point radius
(``env.view_point_radius_m``, Habitat's 1.0 m) of the goal object from which the object is
visible. The agent's estimate on its 2D map is the *view region*: cells within ``reach`` of the
detected goal component whose straight line to their nearest goal cell crosses nothing that
hides it (the map's view-blocking cells: obstacles at about camera height, such as walls; a
coffee table does not hide a sofa) other than the object itself (its own cells and those within
``OBJECT_MARGIN_CELLS`` of them are its body, not something in the way). ``reach`` is the
view-point radius less ``agent.stop_margin_m`` (the map's error: goal cells are where the
object's surface was seen, the view points are measured from its footprint).

Planning aims at the traversable part of the view region, not at the goal's own cells (which
are inside the object and never reachable), so an approach ends as soon as it reaches a spot
the task would accept. Standing in the region, the agent turns until the goal lies within half
the field of view less ``agent.stop_view_margin_deg`` of its heading, then calls STOP
(``GoalApproach``). All masks are (h, w) bool in the planning window's cells.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from calnav.agent.config import AgentConfig
from calnav.agent.planner import heading_to
from calnav.agent.projection import dilate
from calnav.agent.semantic_map import MapChannels, MapState
from calnav.envs.task import Action

MIN_VIEW_HALF_DEG = 1.0      # the STOP's facing tolerance never narrows below this, degrees

OBJECT_MARGIN_CELLS = 3      # obstacle cells this close to the goal component belong to the object
LOS_SAMPLES_PER_CELL = 2     # line-of-sight samples per cell of distance


def view_region(goal: np.ndarray, blockers: np.ndarray, reach_cells: float) -> np.ndarray:
    """(h, w) bool: cells within ``reach_cells`` of the ``goal`` component whose segment to
    their nearest goal cell crosses no ``blockers`` cell outside the object (module docstring)."""
    if not goal.any():
        return np.zeros_like(goal)
    dist, idx = ndimage.distance_transform_edt(~goal, return_indices=True)
    cand = np.argwhere((dist <= reach_cells) & ~goal)
    out = goal.copy()
    if len(cand) == 0:
        return out
    target = np.stack([idx[0][cand[:, 0], cand[:, 1]], idx[1][cand[:, 0], cand[:, 1]]], axis=1)
    blocking = blockers & ~dilate(goal, OBJECT_MARGIN_CELLS)
    n = max(2, int(np.ceil(reach_cells * LOS_SAMPLES_PER_CELL)) + 1)
    t = np.linspace(0.0, 1.0, n)
    pts = np.rint(cand[:, None, :] + (target - cand)[:, None, :] * t[None, :, None]).astype(np.int64)
    clear = ~blocking[pts[..., 0], pts[..., 1]].any(axis=1)
    out[cand[clear, 0], cand[clear, 1]] = True
    return out


def nearest_cell(mask: np.ndarray, rc: tuple[int, int]) -> tuple[tuple[int, int], float]:
    """(nearest True cell of ``mask`` to ``rc``, its distance in cells); ``mask`` must hold one."""
    cells = np.argwhere(mask)
    d = np.hypot(*(cells - np.asarray(rc)).T)
    i = int(np.argmin(d))
    return (int(cells[i, 0]), int(cells[i, 1])), float(d[i])


@dataclass(frozen=True)
class Approach:
    """The next move toward a detected component (window cells): ``action`` now (a turn
    toward it, or STOP), else plan to ``target`` (h, w) bool (``dilate_goal``: to it dilated by
    goal_dilation_m, as ``planner.Planner.plan``), else neither: nothing to do about it this
    step. ``mode`` names the move ('goal', 'stop', 'verify', 'look', 'reject': ``agent.evidence``); ``nearest`` is the component's
    cell nearest the agent."""

    mode: str
    nearest: tuple[int, int]
    action: int | None = None
    target: np.ndarray | None = None
    dilate_goal: bool = True


class GoalApproach:
    """The approach to an accepted goal (module docstring). ``env``: the task's facts
    (``agent.setup.SensorSetup``: ``view_point_radius_m``, ``hfov_deg``)."""

    def __init__(self, cfg: AgentConfig, env):
        self.cfg = cfg
        # the task's view points reach view_point_radius_m from the goal: STOP inside that, less
        # the map's error (or less only blocked_stop_margin_m once a step toward it is blocked)
        radius = float(env.view_point_radius_m)
        if not cfg.blocked_stop_margin_m <= cfg.stop_margin_m < radius:
            raise ValueError(f"need agent.blocked_stop_margin_m ({cfg.blocked_stop_margin_m}) <= "
                             f"agent.stop_margin_m ({cfg.stop_margin_m}) < env.view_point_radius_m ({radius})")
        self.reach_cells = (radius - cfg.stop_margin_m) / cfg.cell_m
        self.blocked_reach_cells = (radius - cfg.blocked_stop_margin_m) / cfg.cell_m
        self.view_half_rad = math.radians(max(env.hfov_deg / 2 - cfg.stop_view_margin_deg, MIN_VIEW_HALF_DEG))

    def next(self, goal: np.ndarray, state: MapState, win: tuple[slice, slice], agent_rc: tuple[int, int],
             yaw: float, free: np.ndarray, collided: bool) -> Approach:
        """The next move toward the goal component ``goal`` (h, w) of window ``win`` of
        ``state``: inside its view region (the blocked reach after a blocked forward,
        ``collided``), turn to face it, then STOP; outside, plan to the region's floor seen
        free (else its cells free in ``free`` (h, w), else the goal itself, dilated)."""
        reach = self.blocked_reach_cells if collided else self.reach_cells
        region = view_region(goal, state.channels[MapChannels.VIEW_BLOCK][win], reach)
        nearest = nearest_cell(goal, agent_rc)[0]
        if region[agent_rc]:
            ang = heading_to(agent_rc, nearest, yaw)
            if abs(ang) > self.view_half_rad:
                return Approach("goal", nearest, action=int(Action.TURN_LEFT if ang > 0 else Action.TURN_RIGHT))
            return Approach("stop", nearest, action=int(Action.STOP))
        # aim at floor seen free (not at unseen cells: a scan's floor holes look like those)
        target = region & state.traversable(self.cfg, win) & ~goal
        if not target.any():
            target = region & free & ~goal
        return Approach("goal", nearest, target=target if target.any() else goal, dilate_goal=not target.any())
