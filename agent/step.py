"""What one step of an agent returns: ``Step``, the one typed result every reader takes.

An agent of ``agent.registry.AGENTS`` answers ``act(obs)`` with a ``Step``: its action and what
it decided it from. The episode loop (``eval.rollout``) sends ``step.action`` and hands the
step to its hooks (the video panel ``agent.visualize``, the Rerun recording ``agent.recording``,
the map sampler of ``calnav collect-maps``); the library (``agent.navigator.Navigator``) turns
it into its ``Decision`` in metres, which ``calnav replay`` and habitat-lab's ``Agent``
(``agent.habitat_agent``) read. Nobody reads the agent's attributes.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np

if TYPE_CHECKING:
    from calnav.agent.goal_detection import GoalDetection
    from calnav.agent.planner import Plan
    from calnav.agent.semantic_map import MapState
    from calnav.mapping.frame import SegmentedFrame


@dataclass
class StepInfo:
    """What the agent decided and why (for visualisation): mode is one of 'spin', 'untrap' (the escape),
    'goal', 'verify', 'look' (a second look at a goal, ``agent.evidence``), 'explore', 'stop' ('stairs' in a house with storeys). detection / plan /
    long_term_goal are in window coordinates (``window`` = (row slice, col slice) of the map),
    frontiers in map coordinates."""

    mode: str
    detection: GoalDetection | None
    plan: Plan | None
    long_term_goal: tuple[int, int] | None
    frontiers: np.ndarray | None
    window: tuple[slice, slice] | None = None


@dataclass(frozen=True, eq=False)   # equal only to itself: it holds the agent's live map
class Step:
    """One step of an agent. ``action``: the ``envs.task.Action`` id it sends; ``steps``: this
    action is the episode's steps-th (1 at the first). A map-less agent (the oracle) leaves the
    rest empty. Of a map agent: ``info`` (``StepInfo``, the decision and why); ``state`` the map
    (``agent.semantic_map.MapState``) with this step's frame in it; ``frame`` that frame
    (``mapping.frame.SegmentedFrame``: depth (h, w) m, k, logits (h, w, K), rgb); ``pose`` (4, 4)
    the start-frame-from-camera pose it was mapped from; ``path`` the map cells (row, col) it
    stood on, this step's last; ``goal_name`` and its map channel ``goal_channel``; the map's
    classes ``class_names`` (K) and cell edge ``cell_m`` metres. ``state`` and ``path`` are the
    agent's own (read them before its next step), not copies: a step costs no copy of the map."""

    action: int
    steps: int
    info: StepInfo | None = None
    state: MapState | None = None
    frame: SegmentedFrame | None = None
    pose: np.ndarray | None = None
    path: Sequence[tuple[int, int]] = ()
    goal_name: str = ""
    goal_channel: int = -1
    class_names: tuple[str, ...] = ()
    cell_m: float = 0.0
