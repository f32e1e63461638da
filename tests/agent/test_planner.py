"""The standalone planner on small grids: it reaches the goal and never steps into an obstacle."""
import math

import numpy as np

from calnav.agent.config import AgentConfig
from calnav.agent.planner import Planner, geodesic_distance, heading_to
from calnav.envs.task import Action

CFG = AgentConfig(cell_m=0.05, goal_dilation_m=0.1, ring_cells=5)
STEP_CELLS = 5        # 0.25 m forward step at 5 cm cells
TURN = math.radians(30)


def simulate(free, start, yaw, goal, max_steps=300):
    """Drive a point agent with the planner on a grid; returns (reached, visited cells)."""
    planner = Planner(CFG)
    pos = np.array(start, float)
    visited = [tuple(pos.astype(int))]
    region = planner.goal_region(goal)
    for _ in range(max_steps):
        rc = (int(round(pos[0])), int(round(pos[1])))
        if region[rc]:
            return True, visited
        plan = planner.plan(free, goal, rc, yaw)
        assert plan.reachable
        if plan.action == Action.TURN_LEFT:
            yaw += TURN
        elif plan.action == Action.TURN_RIGHT:
            yaw -= TURN
        else:
            for _ in range(STEP_CELLS):   # sub-steps: the move must not cross an obstacle
                nxt = pos + (math.sin(yaw), math.cos(yaw))
                cell = (int(round(nxt[0])), int(round(nxt[1])))
                assert free[cell], f"stepped into obstacle at {cell}"
                pos = nxt
                visited.append(cell)
    return False, visited


def test_geodesic_distance_goes_around_a_wall():
    free = np.ones((30, 30), bool)
    free[5:30, 15] = False                       # wall with a gap at the top
    src = np.zeros_like(free)
    src[25, 5] = True
    d = geodesic_distance(free, src)
    assert d[25, 5] == 0 and not np.isfinite(d[25, 15])
    assert d[25, 25] > 35                        # around the wall, not straight through (20)
    assert math.isclose(d[25, 10], 5.0)


def test_geodesic_distance_targets_are_exact_and_stop_early():
    rng = np.random.default_rng(0)
    free = rng.random((80, 80)) > 0.25
    src = np.zeros_like(free)
    src[5, 5] = True
    cost = np.where(rng.random(free.shape) > 0.5, 4.0, 1.0)
    full = geodesic_distance(free, src, cost)
    targets = np.array([[10, 12], [20, 7], [0, 0], [79, 79]])   # near, near, maybe blocked, far
    near = geodesic_distance(free, src, cost, targets=targets[:2])
    for r, c in targets[:2]:
        assert near[r, c] == full[r, c]
    assert np.isinf(near).sum() > np.isinf(full).sum()          # the far cells were not searched
    both = geodesic_distance(free, src, cost, targets=targets)
    for r, c in targets:
        assert both[r, c] == full[r, c] or (np.isinf(both[r, c]) and np.isinf(full[r, c]))


def test_heading_to_signs():
    assert math.isclose(heading_to((0, 0), (0, 5), 0.0), 0.0)
    assert math.isclose(heading_to((0, 0), (5, 0), 0.0), math.pi / 2)      # +row = +y = left of +x
    assert math.isclose(heading_to((0, 0), (-5, 0), 0.0), -math.pi / 2)


def test_planner_reaches_goal_in_open_room():
    free = np.ones((60, 60), bool)
    goal = np.zeros_like(free)
    goal[50, 50] = True
    ok, _ = simulate(free, (8, 8), 0.0, goal)
    assert ok


def test_planner_goes_through_door_never_into_wall():
    free = np.ones((80, 80), bool)
    free[:, 38:43] = False                       # thick wall
    free[60:72, 38:43] = True                    # door
    goal = np.zeros_like(free)
    goal[15, 65] = True
    ok, visited = simulate(free, (15, 15), 0.0, goal)
    assert ok
    assert any(60 <= r < 72 and 38 <= c < 43 for r, c in visited)   # went through the door


def test_planner_turns_toward_goal_behind():
    free = np.ones((40, 40), bool)
    goal = np.zeros_like(free)
    goal[20, 2] = True
    plan = Planner(CFG).plan(free, goal, (20, 30), 0.0)     # goal straight behind (heading +col)
    assert plan.action in (Action.TURN_LEFT, Action.TURN_RIGHT)
    plan = Planner(CFG).plan(free, goal, (20, 30), math.pi)  # facing it
    assert plan.action == Action.MOVE_FORWARD


def test_unreachable_goal_is_reported():
    free = np.ones((40, 40), bool)
    free[:, 20] = False
    goal = np.zeros_like(free)
    goal[20, 35] = True
    plan = Planner(CFG).plan(free, goal, (20, 5), 0.0)
    assert not plan.reachable


def test_planner_on_non_square_windows():
    """The planning window is the explored bounding box plus a margin, rarely square. Each axis
    has its own bound: a tall window with the agent and goal at its right edge (a predicted
    goal can lie there) plans instead of indexing past the columns, and in a wide window the
    goal region is dilated beyond column `rows` (it was clipped at the row count)."""
    cfg = AgentConfig()
    planner = Planner(cfg)
    free = np.ones((300, 210), bool)
    goal = np.zeros_like(free)
    goal[150, 209] = True
    plan = planner.plan(free, goal, (100, 207), 0.0)
    assert plan.reachable
    wide = np.zeros((100, 300), bool)
    wide[50, 200] = True
    region = planner.goal_region(wide)
    rad = int(cfg.goal_dilation_m / cfg.cell_m)
    assert region[50, 200 + rad] and region[50, 200 - rad] and region.sum() > 3 * rad * rad
