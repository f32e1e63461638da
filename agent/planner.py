"""Local planning (standalone): a geodesic distance field to the goal region on the planning
map, a short-term goal on a ring around the agent, and the discrete action toward it.

Distances are geometric Dijkstra costs in cells (8-connected, diagonal steps cost sqrt(2): the
distances of scikit-image's ``MCP_Geometric``, from the compiled kernel ``agent.dijkstra``),
computed on the bounding box of the free cells plus a margin so the cost follows the explored
area, not the map size.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calnav.agent.config import AgentConfig
from calnav.agent.dijkstra import geodesic
from calnav.agent.projection import dilate, disc_offsets
from calnav.envs.task import Action

CROP_MARGIN_CELLS = 4  # extra cells around the free area's bounding box


def free_crop(free: np.ndarray, extra: list[tuple[int, int]]) -> tuple[slice, slice]:
    """Bounding box (row slice, col slice) of the free cells and ``extra`` (row, col) cells,
    plus CROP_MARGIN_CELLS (``free`` must hold a free cell or ``extra`` a cell)."""
    rows, cols = np.flatnonzero(free.any(axis=1)), np.flatnonzero(free.any(axis=0))  # not argwhere: 10x less work
    r = [int(rows[0]), int(rows[-1])] if len(rows) else []
    c = [int(cols[0]), int(cols[-1])] if len(cols) else []
    r += [p[0] for p in extra]
    c += [p[1] for p in extra]
    n0, n1 = free.shape
    return (slice(max(0, min(r) - CROP_MARGIN_CELLS), min(n0, max(r) + CROP_MARGIN_CELLS + 1)),
            slice(max(0, min(c) - CROP_MARGIN_CELLS), min(n1, max(c) + CROP_MARGIN_CELLS + 1)))


def geodesic_distance(free: np.ndarray, sources: np.ndarray, cost: np.ndarray | None = None,
                      targets: np.ndarray | None = None) -> np.ndarray:
    """Geodesic distance (n0, n1) float64 in cells from the bool ``sources`` mask through the
    bool ``free`` mask (inf where unreachable or not free; sources count as free). cost
    (n0, n1) float >= 1: optional per-cell traversal cost (default 1 per cell). targets (M, 2)
    int (row, col): optional; the search stops once every passable target is settled, so
    their values are exact while other cells may hold inf or an upper bound (the planner only
    reads the agent's cell and its ring, and a far frontier goal no longer costs a search over
    the whole explored area)."""
    passable = free | sources
    out = np.full(free.shape, np.inf)
    if not sources.any():
        return out
    src = np.argwhere(sources)
    rs, cs = free_crop(passable, [])
    base = 1.0 if cost is None else cost[rs, cs]
    costs = np.where(passable[rs, cs], base, np.inf)
    ends = None
    if targets is not None:
        t = np.asarray(targets, int).reshape(-1, 2)
        inside = (t[:, 0] >= rs.start) & (t[:, 0] < rs.stop) & (t[:, 1] >= cs.start) & (t[:, 1] < cs.stop)
        t = t[inside]
        ends = t[passable[t[:, 0], t[:, 1]]] - (rs.start, cs.start)
    out[rs, cs] = geodesic(costs, src - (rs.start, cs.start), ends)   # (inf wherever cost is: not passable)
    return out


def inside(cells: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The rows of ``cells`` (M, 2) int (row, col) that lie inside a map of ``shape`` (rows,
    cols). The planning window is rarely square: each axis has its own bound."""
    return cells[((cells >= 0) & (cells < np.asarray(shape[:2]))).all(axis=1)]


def heading_to(agent_rc: tuple[int, int], target_rc, yaw: float) -> float:
    """Signed angle (rad, counter-clockwise positive, in (-pi, pi]) from heading ``yaw`` (rad,
    from world +x = +col) to the direction agent -> target ((row, col) cells; +row = +y)."""
    dy, dx = target_rc[0] - agent_rc[0], target_rc[1] - agent_rc[1]
    return (math.atan2(dy, dx) - yaw + math.pi) % (2 * math.pi) - math.pi


@dataclass
class Plan:
    """action: the Action id; short_term_goal (row, col) or None; distance (n, n) the field
    (cells; exact at the agent and its ring, elsewhere inf or an upper bound) or None;
    reachable: the agent has a finite distance to the goal."""

    action: int
    short_term_goal: tuple[int, int] | None
    distance: np.ndarray | None
    reachable: bool


class Planner:
    """plan(free, goal, agent_rc, yaw) -> Plan toward the goal region."""

    def __init__(self, cfg: AgentConfig):
        self.cfg = cfg
        self.turn_rad = math.radians(cfg.turn_threshold_deg)
        self._ring = self._ring_offsets(cfg.ring_cells)
        self._start_disc = disc_offsets(cfg.agent_radius_m / cfg.cell_m)

    @staticmethod
    def _ring_offsets(radius: int) -> np.ndarray:
        """(M, 2) offsets of the cells at distance in (radius - 1, radius] (a one-cell ring)."""
        d = disc_offsets(radius)
        rr = np.hypot(d[:, 0], d[:, 1])
        return d[rr > radius - 1]

    def goal_region(self, goal: np.ndarray) -> np.ndarray:
        """The goal mask dilated by goal_dilation_m (bool (n, n))."""
        return dilate(goal, self.cfg.goal_dilation_m / self.cfg.cell_m)

    def plan(self, free: np.ndarray, goal: np.ndarray, agent_rc: tuple[int, int], yaw: float,
             dilate_goal: bool = True) -> Plan:
        """free (h, w) bool planning map; goal (h, w) bool goal cells; agent cell; yaw rad.
        dilate_goal: plan to the goal dilated by goal_dilation_m (a frontier, an object's cells),
        or (False) to exactly the goal cells (cells already chosen as reachable targets)."""
        free = free.copy()
        disc = inside(self._start_disc + agent_rc, free.shape)   # the agent's own footprint is never blocked
        free[disc[:, 0], disc[:, 1]] = True
        region = self.goal_region(goal) if dilate_goal else goal
        near_obstacle = dilate(~free, self.cfg.clearance_m / self.cfg.cell_m)
        cost = np.where(near_obstacle, self.cfg.clearance_cost, 1.0)
        ring = inside(self._ring + agent_rc, free.shape)
        dist = geodesic_distance(free, region & free | goal, cost, targets=np.vstack([ring, [agent_rc]]))
        here = dist[agent_rc]
        if not np.isfinite(here):
            return Plan(int(Action.TURN_LEFT), None, dist, False)
        d = dist[ring[:, 0], ring[:, 1]]
        d = np.where(self._line_of_sight(free, agent_rc, ring), d, np.inf)
        if here <= self.cfg.ring_cells or not np.isfinite(d).any():
            # inside the ring of the goal: head straight for the nearest goal-region cell
            stg = tuple(int(v) for v in np.argwhere(region)[np.argmin(np.hypot(*(np.argwhere(region) - agent_rc).T))])
        else:
            stg = tuple(int(v) for v in ring[int(np.argmin(d))])
        return Plan(self.action_toward(agent_rc, stg, yaw), stg, dist, True)

    def _line_of_sight(self, free: np.ndarray, agent_rc, targets: np.ndarray) -> np.ndarray:
        """(M,) bool: the straight segment from the agent to each target cell stays on free
        cells (sampled at half-cell spacing)."""
        t = np.linspace(0.0, 1.0, 2 * self.cfg.ring_cells + 1)
        pts = np.asarray(agent_rc, float) + (targets - agent_rc)[:, None, :] * t[None, :, None]
        cells = np.rint(pts).astype(int)
        return free[cells[..., 0], cells[..., 1]].all(axis=1)

    def action_toward(self, agent_rc: tuple[int, int], target_rc, yaw: float) -> int:
        """TURN toward the target if it is more than turn_threshold_deg off, else FORWARD."""
        if tuple(target_rc) == tuple(agent_rc):
            return int(Action.MOVE_FORWARD)
        ang = heading_to(agent_rc, target_rc, yaw)
        if ang > self.turn_rad:
            return int(Action.TURN_LEFT)
        if ang < -self.turn_rad:
            return int(Action.TURN_RIGHT)
        return int(Action.MOVE_FORWARD)
