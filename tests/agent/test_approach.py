"""Finishing the approach: the view region the agent stops in, the watchdog and the deferral's
set-aside rules, and collision marks that outlive the reset when the same cells are hit again."""
from __future__ import annotations

import numpy as np
import pytest

from calnav.agent.approach import nearest_cell, view_region
from calnav.agent.config import AgentConfig
from calnav.agent.goal_detection import Deferral
from calnav.agent.watchdog import LOOP, STUCK, ProgressWatchdog


def _goal(n: int = 60) -> np.ndarray:
    goal = np.zeros((n, n), bool)
    goal[28:32, 40:46] = True      # the object's seen cells
    return goal


def test_view_region_reach_and_line_of_sight():
    goal = _goal()
    obstacles = goal.copy()
    obstacles[20:40, 30] = True                     # a wall 10 cells left of the object
    obstacles[27:33, 38] = True                     # the object's own (unlabelled) side: not in the way
    region = view_region(goal, obstacles, reach_cells=17)
    assert region[30, 36]                           # 4 cells in front, past the object's own side
    assert region[30, 31] and not region[30, 29]    # just right of the wall; behind it (11 cells): blocked
    assert region[12, 43] and not region[10, 43]    # 16 cells above: within reach; 18: beyond
    assert region[goal].all()


def test_view_region_empty_goal_and_nearest_cell():
    assert not view_region(np.zeros((10, 10), bool), np.zeros((10, 10), bool), 5).any()
    (r, c), d = nearest_cell(_goal(), (30, 30))
    assert (r, c) == (30, 40) and d == pytest.approx(10.0)


def _looping(dog: ProgressWatchdog, steps: int) -> list[str | None]:
    """Feed positions going round a 0.5 m circle (moving, never leaving 1.5 m)."""
    out = []
    for i in range(steps):
        a = i * 0.3
        out.append(dog.observe(np.array([0.5 * np.cos(a), 0.5 * np.sin(a)]), escaping=False))
    return out


def test_watchdog_loop_and_set_aside_rules():
    cfg = AgentConfig(loop_steps=40, stuck_steps=10, stuck_radius_m=0.05)
    deferral = Deferral(cfg, 20)
    dog = ProgressWatchdog(cfg, deferral)
    events = _looping(dog, 40)
    assert events[-1] == LOOP and events.count(LOOP) == 1
    comp = np.zeros((20, 20), bool)
    comp[5:8, 5:8] = True
    assert not deferral.defer(comp, within_reach=True)        # the agent is within reach: never hidden
    assert deferral.hidden() is None
    assert deferral.defer(comp, within_reach=False)
    assert deferral.hidden() is not None and deferral.hidden()[6, 6]
    # the set-aside lasts loop_steps; the loop check starts afresh when it ends, so it cannot fire
    # on the very step the goal comes back (they used to run in lockstep)
    events = _looping(dog, 40)
    assert deferral.hidden() is None and LOOP not in events
    events = _looping(dog, 40)
    assert events.count(LOOP) == 1 and events.index(LOOP) >= 38   # a full window after the end
    assert not deferral.defer(comp, within_reach=False)       # never the same component twice in a row
    other = np.roll(comp, 8, axis=0)
    assert deferral.defer(other, within_reach=False)


def test_a_loop_defers_the_component_headed_for_unless_within_reach():
    """``GoalDetector.defer_heading``: the window's component goes to map cells; it is set aside
    only when the agent is farther than the reach from every cell of it, and then hidden from
    detection until the deferral ends."""
    from calnav.agent.goal_detection import GoalDetector

    cfg = AgentConfig(loop_steps=5, goal_threshold=0.5, goal_min_area_cells=1)
    detector = GoalDetector(cfg, 30)
    win = (slice(10, 20), slice(10, 20))
    comp = np.zeros((10, 10), bool)
    comp[2:4, 2:4] = True                                   # map cells (12..13, 12..13)
    assert not detector.defer_heading(comp, win, (12, 16), reach_cells=3.0)   # 3 cells away: within reach
    conf = comp.astype(np.float32)
    assert detector.detect(conf, win)[0].found
    assert detector.defer_heading(comp, win, (12, 17), reach_cells=3.0)       # 4 cells away: deferred
    assert detector.deferral.hidden()[12, 12] and not detector.detect(conf, win)[0].found
    for _ in range(cfg.loop_steps):
        detector.deferral.tick()
    assert detector.deferral.hidden() is None and detector.detect(conf, win)[0].found


def test_watchdog_stuck():
    cfg = AgentConfig(stuck_steps=10, stuck_radius_m=0.3)
    dog = ProgressWatchdog(cfg, Deferral(cfg, 10))
    events = [dog.observe(np.zeros(2), escaping=False) for _ in range(10)]
    assert events[-1] == STUCK and events.count(STUCK) == 1
    assert all(dog.observe(np.zeros(2), escaping=True) is None for _ in range(30))


def test_collision_marks_hit_twice_outlive_the_reset():
    """A blocked forward marks the strip ahead; when exploration finds nothing reachable, marks
    hit once are forgotten (a doorway may be behind them), marks hit again stay (a floor hole or
    step the agent cannot see and would walk into again)."""
    from calnav.agent.collision import CollisionMarks
    from calnav.agent.semantic_map import MapChannels, MapState

    cfg = AgentConfig(map_size_m=8.0)
    state = MapState.empty(np.zeros(2), cfg, 3)
    marks = CollisionMarks(cfg, state.size)
    marks.mark(state, np.array([0.0, 0.0]), 0.0)             # hit once, facing +x
    marks.mark(state, np.array([0.0, 0.0]), np.pi / 2)        # hit once, facing +y
    marks.mark(state, np.array([0.0, 0.0]), np.pi / 2)        # ... and again
    channel = state.channels[MapChannels.COLLISION]
    ahead_x, ahead_y = state.to_cell((0.3, 0.0), 0.05), state.to_cell((0.0, 0.3), 0.05)
    assert channel[ahead_x] and channel[ahead_y]
    marks.forget(state)
    assert not channel[ahead_x] and channel[ahead_y]
