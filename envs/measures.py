"""ObjectNav measures, with habitat-lab's definitions (``habitat.tasks.nav.nav``).

Each measure follows habitat-lab's ``Measure`` protocol: ``reset_metric`` at episode start and
``update_metric`` after every action, with explicit dependencies on other measures (resolved by
``Measurements``, which updates them in dependency order).

What differs from habitat-lab:
- names: the SoftSPL measure's uuid (its key in the env's ``info`` and in results files) is
  ``softspl``; habitat-lab's ``SoftSPL.cls_uuid`` is ``soft_spl``. The other uuids
  (``distance_to_goal``, ``success``, ``spl``) are habitat-lab's.
- positions are the agent's 2D floor position, so L sums 2D step lengths (habitat-lab: 3D agent
  positions; the same on a single floor). In a house with storeys the env hands (x, y, floor
  height), so L counts the climb as habitat-lab's does.
- where habitat-lab divides by zero (start distance d_0 = 0: SoftSPL always, SPL when L = 0
  too), calnav's SPL and SoftSPL are 0.

- DistanceToGoal d_t: geodesic distance (metres) from the agent to the nearest view point of
  any instance of the goal category.
- Success: 1 if STOP was called and d_T < success_distance (0.1 m), else 0.
- SPL = Success * d_0 / max(d_0, L), L = sum of Euclidean step lengths actually travelled.
- SoftSPL = max(0, 1 - d_T / d_0) * d_0 / max(d_0, L).

One measure is calnav's own (not habitat-lab's), a diagnostic that no score reads:
- StepsAtGoal (``steps_at_goal``): the longest run of consecutive steps in which a STOP would
  have succeeded (d_t < success distance) with a goal instance in view, without a STOP -- an
  approach that does not end.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Callable

import numpy as np


@dataclass
class TaskState:
    """What the measures read after each step.

    position: (2,) float64 agent floor position, metres ((3,) with the floor height in a house
    with storeys). stop_called: STOP was the last action.
    distance_fn: position (2,) -> geodesic DistanceToGoal in metres (inf if unreachable).
    goal_in_view: some pixel of the current frame shows a goal instance.
    """

    position: np.ndarray
    distance_fn: Callable[[np.ndarray], float]
    stop_called: bool = False
    goal_in_view: bool = False
    measures: dict[str, "Measure"] = field(default_factory=dict)


class Measure(ABC):
    uuid: str = ""
    dependencies: tuple[str, ...] = ()

    def __init__(self) -> None:
        self.metric: float = 0.0

    @abstractmethod
    def reset_metric(self, task: TaskState) -> None:
        """Initialise at episode start (after the agent is placed)."""

    @abstractmethod
    def update_metric(self, task: TaskState) -> None:
        """Update after an action was applied."""


class DistanceToGoal(Measure):
    uuid = "distance_to_goal"

    def reset_metric(self, task: TaskState) -> None:
        self.update_metric(task)

    def update_metric(self, task: TaskState) -> None:
        self.metric = float(task.distance_fn(task.position))


class Success(Measure):
    uuid = "success"
    dependencies = ("distance_to_goal",)

    def __init__(self, success_distance: float) -> None:
        super().__init__()
        self.success_distance = success_distance

    def reset_metric(self, task: TaskState) -> None:
        self.update_metric(task)

    def update_metric(self, task: TaskState) -> None:
        d = task.measures["distance_to_goal"].metric
        self.metric = 1.0 if (task.stop_called and d < self.success_distance) else 0.0


class SPL(Measure):
    """Success weighted by (normalised inverse) Path Length."""

    uuid = "spl"
    dependencies = ("distance_to_goal", "success")

    def reset_metric(self, task: TaskState) -> None:
        self._previous = np.array(task.position, dtype=np.float64)
        self._start_end_distance = task.measures["distance_to_goal"].metric
        self._agent_distance = 0.0
        self.update_metric(task)

    def _advance_path(self, task: TaskState) -> None:
        """Add the step to ``task.position`` to the travelled path length L."""
        position = np.array(task.position, dtype=np.float64)
        self._agent_distance += float(np.linalg.norm(position - self._previous))
        self._previous = position

    def _path_ratio(self) -> float:
        """d_0 / max(d_0, L) of the path travelled so far (0 when both are 0); no side effects."""
        d0 = self._start_end_distance
        return d0 / max(d0, self._agent_distance) if max(d0, self._agent_distance) > 0 else 0.0

    def update_metric(self, task: TaskState) -> None:
        self._advance_path(task)
        self.metric = task.measures["success"].metric * self._path_ratio()

    @property
    def path_length(self) -> float:
        return self._agent_distance


class SoftSPL(SPL):
    """SPL with a soft success: progress towards the goal, max(0, 1 - d_T / d_0).

    uuid ``softspl`` (habitat-lab's ``SoftSPL.cls_uuid`` is ``soft_spl``; calnav keeps
    ``softspl`` because results files are keyed by it)."""

    uuid = "softspl"
    dependencies = ("distance_to_goal",)

    def update_metric(self, task: TaskState) -> None:
        d0 = self._start_end_distance
        d = task.measures["distance_to_goal"].metric
        soft_success = max(0.0, 1.0 - d / d0) if d0 > 0 else 0.0
        self._advance_path(task)
        self.metric = soft_success * self._path_ratio()


class StepsAtGoal(Measure):
    """Longest run of consecutive steps spent where STOP would have succeeded, the goal in
    view, without calling STOP (see the module docstring)."""

    uuid = "steps_at_goal"
    dependencies = ("distance_to_goal",)

    def __init__(self, success_distance: float) -> None:
        super().__init__()
        self.success_distance = success_distance

    def reset_metric(self, task: TaskState) -> None:
        self._run = 0
        self.metric = 0.0

    def update_metric(self, task: TaskState) -> None:
        at_goal = task.measures["distance_to_goal"].metric < self.success_distance and task.goal_in_view
        self._run = self._run + 1 if at_goal and not task.stop_called else 0
        self.metric = float(max(self.metric, self._run))


class Measurements:
    """Owns the measures of a task and updates them in dependency order."""

    def __init__(self, measures: list[Measure]):
        self._by_uuid = {m.uuid: m for m in measures}
        self._order = self._topological_order()

    def _topological_order(self) -> list[Measure]:
        order: list[Measure] = []
        visiting: set[str] = set()

        def visit(uuid: str) -> None:
            if uuid in (m.uuid for m in order):
                return
            if uuid in visiting:
                raise ValueError(f"measure dependency cycle through {uuid!r}")
            if uuid not in self._by_uuid:
                raise ValueError(f"a measure depends on {uuid!r}, which is not registered; "
                                 f"registered: {', '.join(self._by_uuid)}")
            visiting.add(uuid)
            for dep in self._by_uuid[uuid].dependencies:
                visit(dep)
            visiting.discard(uuid)
            order.append(self._by_uuid[uuid])

        for uuid in self._by_uuid:
            visit(uuid)
        return order

    def reset(self, task: TaskState) -> None:
        task.measures = self._by_uuid
        for m in self._order:
            m.reset_metric(task)

    def update(self, task: TaskState) -> None:
        task.measures = self._by_uuid
        for m in self._order:
            m.update_metric(task)

    def metrics(self) -> dict[str, float]:
        return {uuid: m.metric for uuid, m in self._by_uuid.items()}

    def __getitem__(self, uuid: str) -> Measure:
        return self._by_uuid[uuid]


def objectnav_measurements(success_distance: float) -> Measurements:
    return Measurements([DistanceToGoal(), Success(success_distance), SPL(), SoftSPL(),
                         StepsAtGoal(success_distance)])
