"""habitat-lab ObjectNav measures against hand-computed trajectories."""
import numpy as np
import pytest

from calnav.envs.measures import Measurements, Measure, TaskState, objectnav_measurements


def straight_line_task(goal_x: float):
    """Agent on a line; the goal view point region is x >= goal_x (distance = goal_x - x)."""
    return TaskState(position=np.zeros(2), distance_fn=lambda p: max(0.0, goal_x - float(p[0])))


def run(task, measurements, path, stop_at_end=True):
    measurements.reset(task)
    for i, p in enumerate(path):
        task.position = np.asarray(p, dtype=float)
        task.stop_called = stop_at_end and i == len(path) - 1
        measurements.update(task)
    return measurements.metrics()


def test_direct_success_spl_one():
    task = straight_line_task(1.0)
    m = run(task, objectnav_measurements(0.1), [(0.25, 0), (0.5, 0), (0.75, 0), (1.0, 0), (1.0, 0)])
    assert m == pytest.approx({"distance_to_goal": 0.0, "success": 1.0, "spl": 1.0, "softspl": 1.0,
                               "steps_at_goal": 0.0})


def test_detour_spl_hand_computed():
    # d0 = 1.0; path: up 0.5, across 1.0 diagonal-free, down 0.5 -> L = 0.5 + 1.0 + 0.5 = 2.0
    task = straight_line_task(1.0)
    m = run(task, objectnav_measurements(0.1), [(0, 0.5), (1.0, 0.5), (1.0, 0.0)])
    assert m["success"] == 1.0
    assert m["spl"] == pytest.approx(1.0 / 2.0)
    assert m["softspl"] == pytest.approx(1.0 / 2.0)


def test_stop_short_of_goal_fails_but_softspl_counts_progress():
    # d0 = 2.0, agent walks 1.5 m straight and stops: d_T = 0.5
    task = straight_line_task(2.0)
    m = run(task, objectnav_measurements(0.1), [(0.5, 0), (1.0, 0), (1.5, 0)])
    assert m["distance_to_goal"] == pytest.approx(0.5)
    assert m["success"] == 0.0 and m["spl"] == 0.0
    assert m["softspl"] == pytest.approx((1 - 0.5 / 2.0) * 2.0 / 2.0)


def test_success_threshold():
    task = straight_line_task(1.0)
    m = run(task, objectnav_measurements(0.1), [(0.85, 0)])  # d_T = 0.15 >= 0.1
    assert m["success"] == 0.0
    task = straight_line_task(1.0)
    m = run(task, objectnav_measurements(0.1), [(0.95, 0)])
    assert m["success"] == 1.0
    assert m["spl"] == pytest.approx(1.0)  # L = 0.95 < d0 = 1.0 -> ratio capped at 1


def test_reaching_goal_without_stop_is_not_success():
    task = straight_line_task(0.5)
    m = run(task, objectnav_measurements(0.1), [(0.25, 0), (0.5, 0)], stop_at_end=False)
    assert m["success"] == 0.0 and m["spl"] == 0.0
    assert m["softspl"] == pytest.approx(1.0)


def test_overshoot_softspl_clipped_at_zero():
    # moving away: d_T > d0 -> soft success max(0, 1 - d/d0) = 0
    task = straight_line_task(1.0)
    m = run(task, objectnav_measurements(0.1), [(-1.0, 0)])
    assert m["softspl"] == 0.0


def test_dependency_cycle_and_missing_dependency_errors():
    class A(Measure):
        uuid, dependencies = "a", ("b",)

        def reset_metric(self, task): ...

        def update_metric(self, task): ...

    class B(A):
        uuid, dependencies = "b", ("a",)

    with pytest.raises(ValueError, match="cycle"):
        Measurements([A(), B()])
    with pytest.raises(ValueError, match="not registered"):
        Measurements([A()])
