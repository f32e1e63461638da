"""Finishing the approach: the view region the agent stops in, the watchdog's set-aside rules,
and collision marks that outlive the reset when the same cells are hit again."""
from __future__ import annotations

import numpy as np
import pytest

from calnav.agent.approach import nearest_cell, view_region
from calnav.agent.config import AgentConfig
from calnav.agent.watchdog import ProgressWatchdog


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
    dog = ProgressWatchdog(cfg, 20)
    events = _looping(dog, 40)
    assert events[-1] == "loop" and events.count("loop") == 1
    comp = np.zeros((20, 20), bool)
    comp[5:8, 5:8] = True
    assert not dog.set_aside(comp, within_reach=True)        # the agent is within reach: never hidden
    assert dog.hidden() is None
    assert dog.set_aside(comp, within_reach=False)
    assert dog.hidden() is not None and dog.hidden()[6, 6]
    # the set-aside lasts loop_steps; the loop check starts afresh when it ends, so it cannot fire
    # on the very step the goal comes back (they used to run in lockstep)
    events = _looping(dog, 40)
    assert dog.hidden() is None and "loop" not in events
    events = _looping(dog, 40)
    assert events.count("loop") == 1 and events.index("loop") >= 38   # a full window after the end
    assert not dog.set_aside(comp, within_reach=False)       # never the same component twice in a row
    other = np.roll(comp, 8, axis=0)
    assert dog.set_aside(other, within_reach=False)


def test_watchdog_stuck():
    cfg = AgentConfig(stuck_steps=10, stuck_radius_m=0.3)
    dog = ProgressWatchdog(cfg, 10)
    events = [dog.observe(np.zeros(2), escaping=False) for _ in range(10)]
    assert events[-1] == "stuck" and events.count("stuck") == 1
    assert all(dog.observe(np.zeros(2), escaping=True) is None for _ in range(30))


def test_collision_marks_hit_twice_outlive_the_reset():
    """A blocked forward marks the strip ahead; when exploration finds nothing reachable, marks
    hit once are forgotten (a doorway may be behind them), marks hit again stay (a floor hole or
    step the agent cannot see and would walk into again)."""
    from calnav.agent.policy import PeanutAgent
    from calnav.agent.semantic_map import MapChannels
    from calnav.eval.config import load_config

    cfg = load_config(None, ["env.resolution=64x48", "agent.map_resolution=64x48", "agent.map_size_m=8",
                             "mapping.initial_alloc_mb=16"])
    agent = PeanutAgent(cfg)
    h, w = 48, 64
    agent.reset({"rgb": np.zeros((h, w, 3), np.uint8), "depth": np.zeros((h, w, 1), np.float32),
                 "gps": np.zeros(2, np.float32), "compass": np.zeros(1, np.float32), "objectgoal": np.array([0]),
                 "semantic": np.full((h, w), -1, np.int16)})
    agent._mark_collision(np.array([0.0, 0.0]), 0.0)             # hit once, facing +x
    agent._mark_collision(np.array([0.0, 0.0]), np.pi / 2)        # hit once, facing +y
    agent._mark_collision(np.array([0.0, 0.0]), np.pi / 2)        # ... and again
    marks = agent.state.channels[MapChannels.COLLISION]
    ahead_x, ahead_y = agent.state.to_cell((0.3, 0.0), 0.05), agent.state.to_cell((0.0, 0.3), 0.05)
    assert marks[ahead_x] and marks[ahead_y]
    agent._forget_collisions()
    assert not marks[ahead_x] and marks[ahead_y]
