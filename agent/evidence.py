"""The decide stage's evidence: what the agent knows about a detected goal object before it calls
STOP, and the decision that reads it (``agent.decision``, ``agent.registry.DECISIONS``).

- ``threshold`` (``ThresholdDecision``, PEANUT / SemExp): a component accepted by the goal
  threshold is approached and STOP is called on arrival, whatever the evidence behind it.
- ``evidence`` (``EvidenceDecision``): before STOP, an uncertainty test on the object's
  evidence accumulated over views (as "Perception Matters" tests the fused class distribution
  before declaring "found", and ApexNav fuses target evidence over frames). The component was
  accepted on the map's fused confidence (``agent.goal_threshold`` on the ``mapping.fusion``
  map: RBU, averaging and GLFS accept differently from the same frames); the test then asks what
  that confidence rests on, the same way for every fusion:

  * ``n``: the views -- the most frames that saw any one of the component's cells (points of an
    object's heights, ``agent.obstacle_min_height_m`` to ``OBJECT_TOP_M``: a component seen only
    on the floor, a rug read as a bed, has none);
  * ``mean`` and ``spread``: the mean and standard deviation of the per-view goal probability
    (each frame's calibrated softmax(logits / ``mapping.temperature``), averaged over the points
    of a cell), pooled over the component's cells.

  STOP passes when ``n >= evidence_min_views`` and the lower bound
  ``mean - evidence_z * spread / sqrt(n) >= evidence_confidence``: the views, on the whole,
  say "goal". Otherwise the agent takes a *second look* from a view point whose bearing to the
  object no view has had yet (``evidence_looks`` of them, about ``evidence_look_distance_m``
  from the object), and when the test still fails after the last look the component is rejected
  for the rest of the episode (``GoalDetector.rejected``). The looks are counted per object (the
  cells of the component a look was for), not per episode: when the goal moves to another
  component (a larger one under ``goal_choice: largest``), that one has its own looks, and a
  look under way for the one before is dropped.

The same evidence can choose the goal among the accepted components (``agent.goal_choice:
evidence``, ``EvidenceChoice``): the strongest evidence rather than the largest area.

``GoalEvidence`` is the per-episode state (per map cell: views, per-view probability sums,
bearings seen); the decisions are stateless but for their per-object look accounting. Masks are (n, n) bool map
cells or (h, w) cells of the planning window ``win`` where a method says so.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from calnav.agent import projection as pj
from calnav.agent.approach import Approach, view_region
from calnav.agent.config import AgentConfig
from calnav.agent.goal_detection import GoalDetection
from calnav.agent.semantic_map import MapChannels, MapState
from calnav.agent.segmenters import softmax
from calnav.mapping.frame import SegmentedFrame

BEARING_BINS = 8          # bearings of the views on an object, 45-degree sectors (one bit each of a uint8)
LOOK_ARRIVED_CELLS = 3    # a second look is taken once the agent is this close to its view point, cells
# Points of an object: from agent.obstacle_min_height_m (the floor and what lies flat on it -- a rug
# read as a bed -- are no view of an object) up to this height above the floor, metres. Not the
# camera's height: real TVs hang on walls above a 0.88 m camera; ceilings (2.4 m and up) stay out.
OBJECT_TOP_M = 2.0


@dataclass
class Evidence:
    """One component's evidence (module docstring): p the map's mean goal confidence (what
    accepted it), n views, mean the per-view goal probability's mean, spread its standard
    deviation, bearings the bitmask of sectors it was seen from."""

    p: float
    n: int
    mean: float
    spread: float
    bearings: int

    def lower_bound(self, z: float) -> float:
        """mean - z * spread / sqrt(n) (``-inf`` for an object no view saw)."""
        return self.mean - z * self.spread / math.sqrt(self.n) if self.n else -math.inf


@dataclass
class GoalEvidence:
    """Per-cell view accounting of the goal class for one episode, (n, n) each: views (frames
    that saw object points in the cell), q_sum / q_sq (sum and sum of squares of those views'
    mean goal probability), bearings (uint8 bitmask of the sectors, object to camera)."""

    views: np.ndarray
    q_sum: np.ndarray
    q_sq: np.ndarray
    bearings: np.ndarray

    @classmethod
    def empty(cls, n: int) -> "GoalEvidence":
        return cls(np.zeros((n, n), np.int32), np.zeros((n, n), np.float64), np.zeros((n, n), np.float64),
                   np.zeros((n, n), np.uint8))

    def observe(self, state: MapState, frame: SegmentedFrame, pose: np.ndarray, goal_channel: int,
                cfg: AgentConfig, temperature: float) -> None:
        """Add one frame's views: depth (h, w) m and logits (h, w, K) of ``frame``, pose (4, 4)
        world-from-camera (the pose the map was updated with)."""
        points, pix = pj.backproject(frame.depth, frame.k, pose)
        band = pj.obstacle_points(points, cfg.obstacle_min_height_m, OBJECT_TOP_M)
        n = state.size
        cells, inside = pj.cell_of(points[:, :2], state.origin, cfg.cell_m, n)
        keep = band & inside
        if not keep.any():
            return
        logits = frame.logits.reshape(-1, frame.logits.shape[-1])[pix[keep]]
        goal = softmax(logits, temperature)[:, goal_channel]
        u, sums, counts = pj.sparse_bin_sums(cells[keep], goal.astype(np.float32))
        q = sums / counts                                   # this view's mean goal probability per cell
        r, c = np.divmod(u, n)
        xy = state.origin + (np.stack([c, r], 1) + 0.5) * cfg.cell_m
        away = np.arctan2(pose[1, 3] - xy[:, 1], pose[0, 3] - xy[:, 0])   # from the object to the camera
        sector = (np.floor((away % (2 * np.pi)) / (2 * np.pi) * BEARING_BINS).astype(np.int64)) % BEARING_BINS
        self.views.reshape(-1)[u] += 1
        self.q_sum.reshape(-1)[u] += q
        self.q_sq.reshape(-1)[u] += q * q
        self.bearings.reshape(-1)[u] |= (1 << sector).astype(np.uint8)

    def of(self, mask: np.ndarray, confidence: np.ndarray, win: tuple[slice, slice]) -> Evidence:
        """The evidence of the component ``mask`` (h, w) of window ``win``; ``confidence`` (h, w)
        the map's goal confidence there."""
        views = self.views[win][mask]
        total = int(views.sum())
        p = float(confidence[mask].mean()) if mask.any() else 0.0
        if total == 0:
            return Evidence(p, 0, 0.0, 0.0, 0)
        mean = float(self.q_sum[win][mask].sum() / total)
        var = max(float(self.q_sq[win][mask].sum() / total) - mean * mean, 0.0)
        bearings = int(np.bitwise_or.reduce(self.bearings[win][mask]))
        return Evidence(p, int(views.max()), mean, math.sqrt(var), bearings)


def passes(ev: Evidence, cfg: AgentConfig) -> bool:
    """The uncertainty test before STOP (module docstring)."""
    return ev.n >= cfg.evidence_min_views and ev.lower_bound(cfg.evidence_z) >= cfg.evidence_confidence


class EvidenceChoice:
    """``agent.goal_choice: evidence``: among the components above the goal threshold, the goal
    is the one whose evidence is strongest -- one that passes the STOP test before one that does
    not, then the higher lower bound (``Evidence.lower_bound``; an object no view saw has none),
    then the larger. The component pursued so far stays the goal unless another is better by a
    tier or by ``goal_choice_margin`` in lower bound, so the agent does not turn back and forth
    between two near-equal objects as their views come in; it stays the goal while a second
    look at it is under way (the look is for it). Each object has its own looks
    (``EvidenceDecision``): coming back to one keeps the looks it had.
    A lower bound is not a probability (it may be negative, or minus infinity for an object no
    view saw), so any seen component replaces a held one no view saw. ``pursued`` (n, n) bool:
    the last component chosen."""

    def __init__(self, cfg: AgentConfig, map_cells: int):
        self.cfg = cfg
        self.pursued = np.zeros((map_cells, map_cells), bool)

    def picker(self, confidence: np.ndarray, win: tuple[slice, slice], decision):
        """The pick over components (h, w) of window ``win``; ``confidence`` (h, w) the map's
        goal confidence there, ``decision`` the ``EvidenceDecision`` whose views it reads."""
        evidence = getattr(decision, "evidence", None)
        if evidence is None:   # the config refuses goal_choice=evidence without decision=evidence
            raise ValueError("agent.goal_choice=evidence needs the evidence decision's views (agent.decision=evidence)")
        cfg = self.cfg

        def pick(masks: list[np.ndarray], areas: list[int]) -> int:
            overlap = [int((m & self.pursued[win]).sum()) for m in masks]
            held = int(np.argmax(overlap)) if max(overlap) > 0 else None
            if held is not None and decision.looking:
                best = held
            else:
                evs = [evidence.of(m, confidence, win) for m in masks]
                keys = [(passes(ev, cfg), ev.lower_bound(cfg.evidence_z)) for ev in evs]
                best = max(range(len(masks)), key=lambda i: (keys[i], areas[i]))
                if held is not None and held != best:
                    (pass_b, lb_b), (pass_h, lb_h) = keys[best], keys[held]
                    if pass_b == pass_h and not lb_b > lb_h + cfg.goal_choice_margin:
                        best = held
            self.pursued[:] = False
            self.pursued[win] = masks[best]
            return best

        return pick


class ThresholdDecision:
    """``agent.decision: threshold``: STOP on arrival at an accepted component (PEANUT)."""

    def __init__(self, cfg: AgentConfig, temperature: float):
        self.cfg = cfg

    def reset(self, n: int) -> None:
        """A new episode on an (n, n) map."""

    def observe(self, state: MapState, frame: SegmentedFrame, pose: np.ndarray, goal_channel: int) -> None:
        """Nothing to accumulate."""

    def review(self, move: Approach, det: GoalDetection, state: MapState, goal_channel: int,
               win: tuple[slice, slice], agent_rc: tuple[int, int], free: np.ndarray) -> Approach:
        """The approach's move, unchanged."""
        return move

    def abandon(self) -> None:
        """The look under way cannot be carried out (its view point is unreachable)."""

    @property
    def looking(self) -> bool:
        """Whether a second look is under way."""
        return False


class EvidenceDecision(ThresholdDecision):
    """``agent.decision: evidence``: the uncertainty test before STOP, a second look when it
    fails, rejection after the last look (module docstring). ``temperature``: the per-view
    probabilities' (``mapping.temperature``)."""

    def __init__(self, cfg: AgentConfig, temperature: float):
        super().__init__(cfg, temperature)
        self.temperature = temperature
        self.evidence: GoalEvidence | None = None
        self.looked: np.ndarray | None = None       # (n, n) int16: second looks taken at the object on each cell
        self.look_for: np.ndarray | None = None     # (n, n) bool: the object the look under way is for
        self.target: tuple[int, int] | None = None  # the view point of the look under way (map cell)
        self.last: Evidence | None = None           # the evidence the last test read (for traces)

    def reset(self, n: int) -> None:
        self.evidence = GoalEvidence.empty(n)
        self.looked = np.zeros((n, n), np.int16)
        self.look_for = np.zeros((n, n), bool)
        self.target, self.last = None, None

    def looks(self, mask: np.ndarray, win: tuple[slice, slice]) -> int:
        """Second looks taken at the object ``mask`` (h, w) of window ``win``: the most taken at
        any of its cells (a component grows and merges as the map does; its looks stay)."""
        return int(self.looked[win][mask].max()) if mask.any() else 0

    def observe(self, state: MapState, frame: SegmentedFrame, pose: np.ndarray, goal_channel: int) -> None:
        self.evidence.observe(state, frame, pose, goal_channel, self.cfg, self.temperature)

    def abandon(self) -> None:
        self.target = None

    @property
    def looking(self) -> bool:
        return self.target is not None

    def passes(self, ev: Evidence) -> bool:
        """The uncertainty test (module docstring)."""
        return passes(ev, self.cfg)

    def review(self, move: Approach, det: GoalDetection, state: MapState, goal_channel: int,
               win: tuple[slice, slice], agent_rc: tuple[int, int], free: np.ndarray) -> Approach:
        """The approach's move, or a second look, or a rejection (an Approach of mode
        ``reject``: the caller rejects ``det.mask``)."""
        w0 = (win[0].start, win[1].start)
        if self.target is not None and not (self.look_for[win] & det.mask).any():
            self.target = None                      # the goal is another object now: the look was for the one before
        if self.target is not None:                 # a look under way: go on until there
            t = (self.target[0] - w0[0], self.target[1] - w0[1])
            if math.dist(t, agent_rc) > LOOK_ARRIVED_CELLS and 0 <= t[0] < free.shape[0] and 0 <= t[1] < free.shape[1]:
                target = np.zeros_like(free)
                target[t] = True
                return Approach("look", move.nearest, target=target)
            self.target = None                      # arrived (or off the window): the look is taken
        if move.mode != "stop":
            return move
        ev = self.last = self.evidence.of(det.mask, state.semantic[goal_channel][win], win)
        if self.passes(ev):
            return move
        if self.looks(det.mask, win) < self.cfg.evidence_looks:
            point = self._view_point(det.mask, ev.bearings, state, win, agent_rc, free)
            if point is not None:
                self.looked[win][det.mask] += 1     # counted when started: an abandoned look is spent too
                self.look_for[:] = False
                self.look_for[win] = det.mask
                self.target = (point[0] + w0[0], point[1] + w0[1])
                target = np.zeros_like(free)
                target[point] = True
                return Approach("look", move.nearest, target=target)
        return Approach("reject", move.nearest)

    def _view_point(self, goal: np.ndarray, seen: int, state: MapState, win: tuple[slice, slice],
                    agent_rc: tuple[int, int], free: np.ndarray) -> tuple[int, int] | None:
        """A traversable cell (window cells) about ``evidence_look_distance_m`` from the
        component ``goal`` with a clear line to it, in a bearing sector no view has had
        (``seen`` bitmask) and, where one is left, not next to one a view had; the nearest to
        the agent, or None."""
        cfg = self.cfg
        reach = cfg.evidence_look_distance_m / cfg.cell_m
        region = view_region(goal, state.channels[MapChannels.VIEW_BLOCK][win], reach)
        dist = ndimage.distance_transform_edt(~goal)
        ok = region & state.traversable(cfg, win) & free & (dist >= reach / 2)
        cells = np.argwhere(ok)
        if len(cells) == 0:
            return None
        centre = np.argwhere(goal).mean(axis=0)
        # bearing from the object to the cell in the map's xy frame (rows are y, columns x)
        away = np.arctan2(cells[:, 0] - centre[0], cells[:, 1] - centre[1])
        sector = (np.floor((away % (2 * np.pi)) / (2 * np.pi) * BEARING_BINS).astype(np.int64)) % BEARING_BINS
        # another view point: a sector no view had, away from those seen (not next to one) where any is left
        near = seen | ((seen << 1) | (seen >> (BEARING_BINS - 1))) & 0xFF | ((seen >> 1) | (seen << (BEARING_BINS - 1))) & 0xFF
        for taken in (near, seen):
            fresh = cells[((taken >> sector) & 1) == 0]
            if len(fresh):
                break
        else:
            return None
        cells = fresh
        i = int(np.argmin(np.hypot(*(cells - np.asarray(agent_rc)).T)))
        return int(cells[i, 0]), int(cells[i, 1])
