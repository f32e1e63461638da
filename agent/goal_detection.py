"""The detect stage: which goal component the agent accepts, which it rejects, which it defers.

- accept (``detect_goal``, PEANUT / SemExp style): threshold the goal class's confidence map
  and keep a connected component big enough: the largest (``agent.goal_choice: largest``) or
  the one with the strongest evidence over views (``evidence``, ``agent.evidence``);
- verify and reject (``agent.uncertainty_aware``): a candidate in the band
  [uncertain_low, goal_threshold) is approached and re-observed; still uncertain within
  ``verify_distance_m`` while facing it, it is rejected for the rest of the episode;
- defer (``Deferral``): when the watchdog (``agent.watchdog``) finds the agent going round in
  circles, the component it was heading for is set aside for ``loop_steps`` steps (a goal seen
  through a hole in a wall, a gap the simulator blocks), so other views can reveal the real way.

``GoalDetector`` holds an episode's rejected cells and its deferral and detects with both
excluded. Masks are (n, n) bool map cells, or (h, w) cells of the planning window ``win``
((row slice, col slice) of the map) where a method says so.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from calnav.agent.approach import Approach, nearest_cell
from calnav.agent.config import AgentConfig
from calnav.agent.planner import heading_to
from calnav.envs.task import Action

CONNECTIVITY = 8  # cells touching at corners belong to one component


@dataclass
class GoalDetection:
    """found: a component passed; mask (n, n) bool the chosen component (all False if not
    found); area in cells; peak the highest confidence in the component."""

    found: bool
    mask: np.ndarray
    area: int
    peak: float


def largest_component(mask: np.ndarray, min_area: int) -> tuple[np.ndarray, int]:
    """The largest 8-connected component of a bool mask (n, n) with at least ``min_area``
    cells, and its area (an all-False mask and 0 when none)."""
    masks, areas = components(mask, min_area, most=1)
    return (masks[0], areas[0]) if masks else (np.zeros_like(mask, bool), 0)


def components(mask: np.ndarray, min_area: int, most: int | None = None) -> tuple[list[np.ndarray], list[int]]:
    """The 8-connected components of a bool mask (n, n) with at least ``min_area`` cells (the
    ``most`` largest, or all): their masks (n, n) bool and areas, largest first (ties in label
    order)."""
    if not mask.any():
        return [], []
    rows, cols = np.nonzero(mask)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1  # crop: cost ~ object size
    num, labels, stats, _ = cv2.connectedComponentsWithStats(mask[r0:r1, c0:c1].astype(np.uint8), connectivity=CONNECTIVITY)
    areas = stats[1:, cv2.CC_STAT_AREA]
    masks, kept = [], []
    for label in np.argsort(-areas, kind="stable")[:most]:
        if areas[label] < min_area:
            break
        out = np.zeros_like(mask, bool)
        out[r0:r1, c0:c1] = labels == label + 1
        masks.append(out)
        kept.append(int(areas[label]))
    return masks, kept


Pick = Callable[[list[np.ndarray], list[int]], int]   # (component masks, areas) -> the chosen one's index


def detect_goal(confidence: np.ndarray, threshold: float, min_area: int, exclude: np.ndarray | None = None,
                pick: Pick | None = None) -> GoalDetection:
    """confidence (n, n) float in [0, 1] of the goal class; cells >= ``threshold`` (and not in
    the optional bool ``exclude`` mask) are candidates; found when a component has >=
    ``min_area`` cells: the largest, or the one ``pick`` chooses among all of them."""
    cand = confidence >= threshold
    if exclude is not None:
        cand &= ~exclude
    if pick is None:
        mask, area = largest_component(cand, min_area)
    else:
        masks, areas = components(cand, min_area)
        i = pick(masks, areas) if masks else -1
        mask, area = (masks[i], areas[i]) if masks else (np.zeros_like(cand, bool), 0)
    peak = float(confidence[mask].max()) if area else 0.0
    return GoalDetection(area > 0, mask, area, peak)


class LargestChoice:
    """``agent.goal_choice: largest`` (PEANUT / SemExp): the largest accepted component."""

    def __init__(self, cfg: AgentConfig, map_cells: int):
        pass

    def picker(self, confidence: np.ndarray, win: tuple[slice, slice], decision) -> Pick | None:
        """None: ``detect_goal``'s own rule, the largest."""
        return None


class Deferral:
    """The component set aside after a loop (``defer``) and for how long: ``loop_steps`` ticks
    of the watchdog's clock (``tick``, once per step after the opening spin).

    Three rules keep the set-aside from hiding a goal the agent needs: a component the agent is
    already within reach of is never set aside; the same component is never set aside twice in
    a row (the second loop only escapes); and the watchdog starts its loop check afresh when a
    set-aside ends (``tick`` says so), so it cannot fire again on the very step the goal comes
    back (both last ``loop_steps``: before, they ran in lockstep and hid a goal for 337 of 500
    steps)."""

    def __init__(self, cfg: AgentConfig, map_cells: int):
        self.cfg = cfg
        self.mask = np.zeros((map_cells, map_cells), bool)   # the component set aside
        self.last = np.zeros_like(self.mask)                  # the one set aside before (never twice in a row)
        self.until = 0                                        # set aside while step < until
        self.step = 0

    def tick(self) -> bool:
        """One step of the clock; whether a set-aside ended on it."""
        self.step += 1
        if self.until and self.step >= self.until:
            self.until = 0
            self.mask[:] = False
            return True
        return False

    def defer(self, component: np.ndarray, within_reach: bool) -> bool:
        """Set ``component`` (n, n) bool aside for loop_steps steps, unless the agent is within
        reach of it or it is the component set aside last time; whether it was."""
        if within_reach or not component.any() or (component & self.last).any():
            return False
        self.mask[:] = component
        self.last[:] = component
        self.until = self.step + self.cfg.loop_steps
        return True

    def hidden(self) -> np.ndarray | None:
        """The set-aside component's mask while the set-aside lasts, else None."""
        return self.mask if self.until else None


class GoalDetector:
    """An episode's goal detection: accept (``detect``), verify and reject (``verify``), defer
    (``defer_heading``, through ``deferral``)."""

    def __init__(self, cfg: AgentConfig, map_cells: int):
        from calnav.agent.registry import GOAL_CHOICES

        self.cfg = cfg
        self.rejected = np.zeros((map_cells, map_cells), bool)   # goal candidates verified as wrong
        self.deferral = Deferral(cfg, map_cells)
        self.choice = GOAL_CHOICES.get(cfg.goal_choice)(cfg, map_cells)   # which accepted component is the goal

    def detect(self, confidence: np.ndarray, win: tuple[slice, slice],
               decision=None) -> tuple[GoalDetection, GoalDetection | None]:
        """(the accepted goal, a candidate to verify or None) in the window: confidence (h, w)
        of the goal class in ``win``; rejected and deferred cells are excluded; ``decision``
        the STOP decision (``agent.evidence``), whose views the goal choice may read. A
        candidate is looked for only when no goal is accepted and ``uncertainty_aware`` is on."""
        cfg = self.cfg
        exclude = self.rejected[win]
        hidden = self.deferral.hidden()
        if hidden is not None:
            exclude = exclude | hidden[win]
        det = detect_goal(confidence, cfg.goal_threshold, cfg.goal_min_area_cells, exclude=exclude,
                          pick=self.choice.picker(confidence, win, decision))
        if det.found or not cfg.uncertainty_aware:
            return det, None
        cand = detect_goal(confidence, cfg.uncertain_low, cfg.goal_min_area_cells, exclude=exclude)
        return det, cand if cand.found else None

    def verify(self, cand: GoalDetection, agent_rc: tuple[int, int], yaw: float, turn_rad: float,
               win: tuple[slice, slice]) -> Approach:
        """The next move on a candidate (window cells): within ``verify_distance_m``, turn to
        face it (beyond ``turn_rad`` rad off the heading ``yaw``), then reject it -- re-observed
        up close and still below the threshold (an Approach with neither action nor target);
        farther, plan to it."""
        nearest, d = nearest_cell(cand.mask, agent_rc)
        if d * self.cfg.cell_m > self.cfg.verify_distance_m:
            return Approach("verify", nearest, target=cand.mask)
        ang = heading_to(agent_rc, nearest, yaw)
        if abs(ang) > turn_rad:
            return Approach("verify", nearest, action=int(Action.TURN_LEFT if ang > 0 else Action.TURN_RIGHT))
        self.rejected[win] |= cand.mask
        return Approach("verify", nearest)

    def defer_heading(self, component: np.ndarray, win: tuple[slice, slice], agent_cell: tuple[int, int],
                      reach_cells: float) -> bool:
        """After a loop: set aside the component (h, w) in window ``win`` that the agent was
        heading for, unless the agent (map cell ``agent_cell``) is within ``reach_cells`` of it
        (``Deferral``); whether it was."""
        full = np.zeros_like(self.rejected)
        full[win] = component
        d = np.hypot(*(np.argwhere(full) - agent_cell).T).min() if full.any() else np.inf
        return self.deferral.defer(full, within_reach=bool(d <= reach_cells))
