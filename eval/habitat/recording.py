"""What ``calnav habitat-benchmark`` puts around habitat-lab's benchmark loop: an env wrapper
that records each episode's result, and a ``habitat.Benchmark`` on an already built env."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from calnav.common.habitat_import import import_habitat
from calnav.common.provenance import running_commit
from calnav.envs.measures import StepsAtGoal, TaskState
from calnav.eval.stats import finite_or_error

habitat = import_habitat()

# habitat-lab measure uuid -> calnav results key
METRIC_KEYS = {"success": "success", "spl": "spl", "soft_spl": "softspl", "distance_to_goal": "distance_to_goal"}


class EnvBenchmark(habitat.Benchmark):
    """``habitat.Benchmark`` on an already built env (its ``__init__`` composes a config from a
    path, without overrides); ``evaluate`` is habitat-lab's ``local_evaluate`` unchanged."""

    def __init__(self, env):  # deliberately no super().__init__: the env exists already
        self._eval_remote = False
        self._env = env


class RecordingEnv:
    """A ``habitat.Env`` as ``Benchmark.local_evaluate`` uses it (reset, step, episode_over,
    get_metrics, episodes), recording one result per episode when its metrics are read (once
    per episode, right after it ends). Collisions, path length and calnav's ``steps_at_goal``
    (``envs.measures.StepsAtGoal``, fed habitat-lab's DistanceToGoal and the simulator's last
    frame) come from the simulator."""

    def __init__(self, env, index_of: dict[tuple[str, str], int], on_record, success_distance: float):
        self.env, self.index_of, self.on_record = env, index_of, on_record
        self.success_distance = success_distance

    @property
    def episodes(self):
        return self.env.episodes

    @property
    def episode_over(self) -> bool:
        return self.env.episode_over

    def reset(self):
        obs = self.env.reset()
        self._t0, self._steps, self._collisions, self._path = time.perf_counter(), 0, 0, 0.0
        self._prev = self.env.sim.position.copy()
        self._stopped = False
        self._goals = np.array([int(g.object_id) for g in self.env.current_episode.goals], np.int64)
        self._at_goal = StepsAtGoal(self.success_distance)
        self._at_goal.reset_metric(self._task_state())
        return obs

    def _task_state(self) -> TaskState:
        """What StepsAtGoal reads, from habitat-lab's measures and the simulator's last frame."""
        d = float(self.env.get_metrics()["distance_to_goal"])
        task = TaskState(position=np.zeros(2), distance_fn=lambda _: d, stop_called=self._stopped,
                         goal_in_view=bool(np.isin(self.env.sim.last_instances, self._goals).any()))
        task.measures = {"distance_to_goal": _Fixed(d)}
        return task

    def step(self, action):
        obs = self.env.step(action)
        sim = self.env.sim
        self._steps += 1
        self._collisions += int(sim.previous_step_collided)
        self._path += float(np.linalg.norm(sim.position - self._prev))
        self._prev = sim.position.copy()
        self._stopped = bool(getattr(self.env.task, "is_stop_called", False))
        self._at_goal.update_metric(self._task_state())
        return obs

    def get_metrics(self) -> dict:
        m = self.env.get_metrics()
        ep = self.env.current_episode
        scene = Path(ep.scene_id).name
        self.on_record(finite_or_error({   # a non-finite metric makes it an error record (eval.stats)
            "index": self.index_of[(scene, ep.episode_id)], "episode_id": f"{scene}:{int(ep.episode_id):03d}",
            "scene": scene, "category": ep.object_category,
            **{ours: float(m[theirs]) for theirs, ours in METRIC_KEYS.items()},
            "geodesic_distance": float(ep.info["geodesic_distance"]), "steps": self._steps,
            "path_length": self._path, "collisions": self._collisions,
            "steps_at_goal": int(self._at_goal.metric), "stop_reason": "stop" if self._stopped else "max_steps",
            "wall_time_s": round(time.perf_counter() - self._t0, 3), "status": "ok", "commit": running_commit(),
        }))
        return m


class _Fixed:
    """A measure holding one value (habitat-lab's DistanceToGoal of this step)."""

    def __init__(self, metric: float):
        self.metric = metric


def episode_index(episodes) -> dict[tuple[str, str], int]:
    """(scene id, habitat episode id) -> calnav episode index. habitat-lab numbers each content
    file's episodes 0, 1, ... (``ObjectNavDatasetV1.from_json``), calnav lists them per scene in
    file order, so the k-th episode of a scene is habitat's episode ``str(k)``."""
    seen: dict[str, int] = {}
    out = {}
    for i, ep in enumerate(episodes):
        k = seen.get(ep.scene_id, 0)
        out[(ep.scene_id, str(k))] = i
        seen[ep.scene_id] = k + 1
    return out


