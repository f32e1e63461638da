"""Frontier-based exploration: frontier = explored free cells 4-adjacent to unknown cells;
components smaller than ``frontier_min_cells`` are dropped; each component is scored by
utility = -geodesic distance (m, from the agent on the traversable map) + frontier_size_weight_m
* size (cells) [+ prior_bonus_m if the semantic prior applies]; the best component's nearest
cell is the long-term goal.

Semantic prior (``semantic_prior: cooccurrence``, off by default): a hand-set table of classes
that co-occur with each goal category in the procedural houses' room-type furniture priors
(e.g. toilet: sink, bathtub; bed: cabinet, shelf). Frontier components within prior_radius_m of
a cell whose arg-max class (confidence >= 0.5) is a related class get prior_bonus_m.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from calnav.agent.config import AgentConfig
from calnav.agent.planner import free_crop, geodesic_distance
from calnav.agent.projection import dilate

# Goal category -> classes usually in the same room (procedural houses' room priors).
COOCCURRENCE: dict[str, tuple[str, ...]] = {
    "chair": ("table", "desk"),
    "bed": ("cabinet", "shelf"),
    "plant": ("sofa", "shelf"),
    "toilet": ("sink", "bathtub"),
    "tv_monitor": ("sofa", "desk", "cabinet"),
    "sofa": ("table", "tv_monitor"),
}
PRIOR_MIN_CONFIDENCE = 0.5    # a class counts as seen at a cell above this confidence
FOUR_NEIGHBOURS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)


def frontier_mask(explored: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Free explored cells 4-adjacent to an unknown cell (bool (n, n))."""
    unknown_near = cv2.dilate((~explored).astype(np.uint8), FOUR_NEIGHBOURS).astype(bool)
    return free & explored & unknown_near


@dataclass
class FrontierChoice:
    """goal (row, col) cell of the chosen frontier; mask (n, n) bool its component; frontiers
    (n, n) bool all kept frontier cells."""

    goal: tuple[int, int]
    mask: np.ndarray
    frontiers: np.ndarray


def prior_mask(semantic: np.ndarray, goal_name: str, class_names: Sequence[str], cfg: AgentConfig
               ) -> np.ndarray | None:
    """Cells near co-occurring classes (bool (n, n)), or None without a prior. semantic
    (K, n, n) confidences of the segmenter's classes ``class_names`` (K); a related class the
    segmenter does not know is skipped."""
    if cfg.semantic_prior == "none":
        return None
    related = [class_names.index(c) for c in COOCCURRENCE.get(goal_name, ()) if c in class_names]
    if not related:
        return None
    seen = (semantic[related] >= PRIOR_MIN_CONFIDENCE).any(axis=0)
    return dilate(seen, cfg.prior_radius_m / cfg.cell_m)


def choose_frontier(explored: np.ndarray, traversable: np.ndarray, agent_rc: tuple[int, int], cfg: AgentConfig,
                    prior: np.ndarray | None = None, exclude: np.ndarray | None = None) -> FrontierChoice | None:
    """The best reachable frontier component (see module docstring), or None if none.
    exclude (n, n) bool: cells not to choose (e.g. frontiers found unreachable). Works on the
    explored area's bounding box, so the cost follows the explored area."""
    if not explored.any():
        return None
    rs, cs = free_crop(explored, [agent_rc])
    local = _choose(explored[rs, cs], traversable[rs, cs], (agent_rc[0] - rs.start, agent_rc[1] - cs.start),
                    cfg, _crop(prior, rs, cs), _crop(exclude, rs, cs))
    if local is None:
        return None
    pad = ((rs.start, explored.shape[0] - rs.stop), (cs.start, explored.shape[1] - cs.stop))
    return FrontierChoice((local.goal[0] + rs.start, local.goal[1] + cs.start), np.pad(local.mask, pad),
                          np.pad(local.frontiers, pad))


def _crop(mask: np.ndarray | None, rs: slice, cs: slice) -> np.ndarray | None:
    return None if mask is None else mask[rs, cs]


def _choose(explored, traversable, agent_rc, cfg, prior, exclude) -> FrontierChoice | None:
    front = frontier_mask(explored, traversable)
    if exclude is not None:
        front &= ~exclude
    if not front.any():
        return None
    num, labels, stats, _ = cv2.connectedComponentsWithStats(front.astype(np.uint8), connectivity=8)
    sizes = stats[:, cv2.CC_STAT_AREA]
    keep = np.flatnonzero(sizes >= cfg.frontier_min_cells)
    keep = keep[keep > 0]
    if len(keep) == 0:
        return None
    start = np.zeros_like(front)
    start[agent_rc] = True
    dist = geodesic_distance(traversable | start, start) * cfg.cell_m
    best, best_u, best_cell = -1, -np.inf, None
    for lab in keep:
        comp = labels == lab
        d = np.where(comp, dist, np.inf)
        i = int(np.argmin(d))
        if not np.isfinite(d.flat[i]):
            continue
        util = -d.flat[i] + cfg.frontier_size_weight_m * sizes[lab]
        if prior is not None and (prior & comp).any():
            util += cfg.prior_bonus_m
        if util > best_u:
            best, best_u, best_cell = lab, util, divmod(i, front.shape[1])
    if best < 0:
        return None
    kept = np.isin(labels, keep)
    return FrontierChoice((int(best_cell[0]), int(best_cell[1])), labels == best, kept)
