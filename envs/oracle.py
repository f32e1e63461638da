"""Privileged agents that use the simulator's ground truth: habitat-lab's ShortestPathFollower
equivalent (for validating episodes, geodesics and metrics) and scanning trajectories.

The follower plans over the agent's real action lattice -- states (x, y, heading) reached by
0.25 m forward steps and 30 degree turns, blocked moves excluded -- with A*: cost = path length
(plus a tiny cost per turn so it prefers fewer turns), heuristic = the geodesic DistanceToGoal
field, goal = DistanceToGoal below the success radius. A greedy "best next step" follower gets
trapped where quantised headings cannot thread a doorway; planning over the lattice cannot.
"""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from calnav.envs.config import EnvConfig
from calnav.envs.lattice import lattice_search
from calnav.envs.layered_lattice import layered_lattice_search
from calnav.envs.motion import apply_action, apply_layered_action
from calnav.envs.task import Action

STOP_RADIUS_FRACTION = 0.99   # STOP once DistanceToGoal < this fraction of the success distance
TURN_COST_M = 1e-3            # tie-breaker: a turn costs as much as 1 mm of path
# A* search tiers, tried in order: (state bin in metres -- positions in one bin per heading are
# one state --, heuristic weight -- the path is at most this factor above the lattice optimum
# --, expanded-state budget). If every tier gives up, a greedy step is taken. The first tier is
# fast and finds almost every path; coarse bins lose the exact position a narrow gap needs
# (a scanned house's neck: 6 cm bins found none of 10 paths that 2 cm bins found 3 of), so the
# second searches finely.
SEARCH_TIERS: tuple[tuple[float, float, int], ...] = ((0.06, 1.05, 40_000), (0.02, 1.0, 1_000_000))


class ShortestPathFollower:
    """next_action(xy (2,) metres, yaw radians, field: GeodesicField) -> Action."""

    def __init__(self, navgrid, env_cfg: EnvConfig, stop_distance_m: float | None = None):
        self.navgrid = navgrid
        self.step_m = env_cfg.forward_step_m
        self.turn_rad = math.radians(env_cfg.turn_angle_deg)
        self.n_headings = max(1, round(2 * math.pi / self.turn_rad))
        # The follower reads the same distance function as the Success measure, so stopping
        # just inside the success radius is safe and saves an overshooting last step.
        self.stop_distance = (stop_distance_m if stop_distance_m is not None
                              else env_cfg.success_distance_m * STOP_RADIUS_FRACTION)
        self._plan: list[tuple[Action, tuple]] = []
        self._field = None

    # ---------------------------------------------------------------- planning
    def _turned(self, heading: float, direction: int) -> float:
        """The env's exact turn arithmetic (so planned and executed poses agree bit for bit)."""
        return (heading + direction * self.turn_rad) % (2 * math.pi)

    def plan(self, xy: np.ndarray, yaw: float, field) -> list[Action] | None:
        """Actions from (xy, yaw) to STOP inside the goal region (the first ``SEARCH_TIERS``
        search that succeeds), or None if every tier gives up."""
        for bin_m, weight, budget in SEARCH_TIERS:
            actions = self._search(xy, yaw, field, bin_m, weight, budget)
            if actions is not None:
                return actions
        return None

    def _search(self, xy: np.ndarray, yaw: float, field, bin_m: float, weight: float,
                budget: int) -> list[Action] | None:
        """One tier's lattice A* (``envs.lattice``), actions ending with STOP, or None."""
        g = self.navgrid
        moves, found = lattice_search(g.navigable, float(g.origin_xy[0]), float(g.origin_xy[1]), float(g.cell_m),
                                      field.distances_m, field.goal_mask, float(xy[0]), float(xy[1]), float(yaw),
                                      float(self.step_m), float(self.turn_rad), int(self.n_headings),
                                      float(self.stop_distance), float(bin_m), float(weight), int(budget),
                                      TURN_COST_M)
        return [Action(int(m)) for m in moves] + [Action.STOP] if found else None

    def _greedy(self, xy: np.ndarray, yaw: float, field) -> Action:
        """Best single step (fallback when planning fails); never STOPs outside the goal."""
        best = (field.distance(xy), None)
        for k in range(self.n_headings):
            new_xy, moved = self.navgrid.move_forward(xy, yaw + k * self.turn_rad, self.step_m)
            if moved and field.distance(new_xy) < best[0]:
                best = (field.distance(new_xy), k)
        if best[1] == 0:
            return Action.MOVE_FORWARD
        if best[1] is not None and best[1] > self.n_headings // 2:
            return Action.TURN_RIGHT
        return Action.TURN_LEFT

    def next_action(self, xy: np.ndarray, yaw: float, field) -> Action:
        if field.distance(xy) < self.stop_distance:
            return Action.STOP
        state = (float(xy[0]), float(xy[1]), float(yaw))
        if field is not self._field or not self._plan or self._plan[0][1] != state:
            self._field = field
            actions = self.plan(xy, yaw, field)
            self._plan = [] if actions is None else self._states(xy, yaw, actions)
            if not self._plan:
                return self._greedy(xy, yaw, field)
        return self._plan.pop(0)[0]

    def _states(self, xy, yaw: float, actions: list[Action]) -> list[tuple[Action, tuple]]:
        """Pair each planned action with the exact (x, y, yaw) it is taken from, so any
        deviation from the plan triggers a replan; [] if a planned step would be blocked."""
        out = []
        pos, heading = np.array(xy, dtype=np.float64), float(yaw)
        for a in actions:
            out.append((a, (float(pos[0]), float(pos[1]), heading)))
            if a == Action.MOVE_FORWARD:
                pos, moved = self.navgrid.move_forward(pos, heading, self.step_m)
                if not moved:
                    return []
            elif a in (Action.TURN_LEFT, Action.TURN_RIGHT):
                heading = self._turned(heading, 1 if a == Action.TURN_LEFT else -1)
        return out


class LayeredFollower(ShortestPathFollower):
    """The follower on a ``LayeredNavGrid``: the layer joins the state (``envs.layered_lattice``);
    next_action(xy, layer, yaw, field: LayeredGeodesicField) -> Action."""

    def plan(self, xy: np.ndarray, layer: int, yaw: float, field) -> list[Action] | None:
        g = self.navgrid
        for bin_m, weight, budget in SEARCH_TIERS:
            moves, found = layered_lattice_search(
                g.navigable, g.floor_heights, float(g.climb_m), float(g.origin_xy[0]), float(g.origin_xy[1]),
                float(g.cell_m), field.distances_m, field.goal_mask, float(xy[0]), float(xy[1]), int(layer), float(yaw),
                float(self.step_m), float(self.turn_rad), int(self.n_headings), float(self.stop_distance), float(bin_m),
                float(weight), int(budget), TURN_COST_M)
            if found:
                return [Action(int(m)) for m in moves] + [Action.STOP]
        return None

    def _greedy_layered(self, xy: np.ndarray, layer: int, yaw: float, field) -> Action:
        best = (field.distance(xy, layer), None)
        for k in range(self.n_headings):
            new_xy, new_layer, moved = self.navgrid.move_forward(xy, layer, yaw + k * self.turn_rad, self.step_m)
            if moved and field.distance(new_xy, new_layer) < best[0]:
                best = (field.distance(new_xy, new_layer), k)
        if best[1] == 0:
            return Action.MOVE_FORWARD
        return Action.TURN_RIGHT if best[1] is not None and best[1] > self.n_headings // 2 else Action.TURN_LEFT

    def next_action(self, xy: np.ndarray, layer: int, yaw: float, field) -> Action:  # type: ignore[override]
        if field.distance(xy, layer) < self.stop_distance:
            return Action.STOP
        state = (float(xy[0]), float(xy[1]), int(layer), float(yaw))
        if field is not self._field or not self._plan or self._plan[0][1] != state:
            self._field = field
            actions = self.plan(xy, layer, yaw, field)
            self._plan = [] if actions is None else self._layered_states(xy, layer, yaw, actions)
            if not self._plan:
                return self._greedy_layered(xy, layer, yaw, field)
        return self._plan.pop(0)[0]

    def _layered_states(self, xy, layer: int, yaw: float, actions: list[Action]) -> list[tuple[Action, tuple]]:
        out = []
        pos, lay, heading = np.array(xy, dtype=np.float64), int(layer), float(yaw)
        for a in actions:
            out.append((a, (float(pos[0]), float(pos[1]), lay, heading)))
            if a == Action.MOVE_FORWARD:
                pos, lay, moved = self.navgrid.move_forward(pos, lay, heading, self.step_m)
                if not moved:
                    return []
            elif a in (Action.TURN_LEFT, Action.TURN_RIGHT):
                heading = self._turned(heading, 1 if a == Action.TURN_LEFT else -1)
        return out


def follower_for(navgrid, env_cfg: EnvConfig) -> ShortestPathFollower:
    """The follower that plans on ``navgrid``: ``LayeredFollower`` on a layered grid."""
    return (LayeredFollower if getattr(navgrid, "layered", False) else ShortestPathFollower)(navgrid, env_cfg)


def layered_oracle_solves(navgrid, env_cfg: EnvConfig, start_xy: np.ndarray, start_layer: int, start_yaw: float,
                          field) -> bool:
    """``oracle_solves`` on a ``LayeredNavGrid`` from (start_xy, start_layer, start_yaw)."""
    actions = LayeredFollower(navgrid, env_cfg).plan(np.asarray(start_xy, dtype=np.float64), int(start_layer),
                                                     float(start_yaw), field)
    if actions is None or len(actions) > env_cfg.dataset.oracle_max_steps:
        return False
    xy, layer, yaw = np.array(start_xy, dtype=np.float64), int(start_layer), float(start_yaw)
    for action in actions[:-1]:
        xy, layer, yaw, _, _ = apply_layered_action(navgrid, env_cfg, xy, layer, yaw, 0.0, action)
    return bool(field.distance(xy, layer) < env_cfg.success_distance_m)


def oracle_solves(navgrid, env_cfg: EnvConfig, start_xy: np.ndarray, start_yaw: float, field) -> bool:
    """Whether the follower's plan from (start_xy (2,) metres, start_yaw radians), executed with
    the env's own motion (``envs.motion``), calls STOP within the success distance of
    ``field``'s goal cells in at most ``env_cfg.dataset.oracle_max_steps`` actions: the check
    that an episode can be solved with the task's discrete actions (a dataset property, like
    Habitat's: a run's own step limit does not change the episodes). No plan within the search
    budget counts as unsolvable."""
    actions = ShortestPathFollower(navgrid, env_cfg).plan(np.asarray(start_xy, dtype=np.float64), float(start_yaw),
                                                          field)
    if actions is None or len(actions) > env_cfg.dataset.oracle_max_steps:
        return False
    xy, yaw = np.array(start_xy, dtype=np.float64), float(start_yaw)
    for action in actions[:-1]:   # the last one is STOP
        xy, yaw, _, _ = apply_action(navgrid, env_cfg, xy, yaw, 0.0, action)
    return bool(field.distance(xy) < env_cfg.success_distance_m)


def scan_trajectory(navgrid, env_cfg: EnvConfig, n_poses: int, seed: int = 0,
                    look_around_every: int = 8) -> list[np.ndarray]:
    """(4, 4) world-from-camera poses of an agent walking shortest paths between far-apart
    points of the house and looking around (a full turn) every ``look_around_every`` steps."""
    from calnav.envs.render import camera_pose

    rng = np.random.default_rng(seed)
    follower = ShortestPathFollower(navgrid, env_cfg)
    height = env_cfg.camera_height_m
    free = np.argwhere(navgrid.navigable)
    xy = navgrid.to_world(free[rng.integers(len(free))][None])[0]
    yaw = float(rng.uniform(0, 2 * math.pi))
    poses: list[np.ndarray] = []
    forward_steps = 0
    while len(poses) < n_poses:
        start_mask = np.zeros(navgrid.navigable.shape, dtype=bool)
        start_mask[tuple(navgrid.to_cell(xy[None])[0])] = True
        dist = navgrid.geodesic_field(start_mask).values
        far = np.argwhere(np.isfinite(dist) & (dist >= 0.5 * np.nanmax(np.where(np.isfinite(dist), dist, 0))))
        target = np.zeros_like(start_mask)
        target[tuple(far[rng.integers(len(far))])] = True
        field = navgrid.geodesic_field(target)
        for _ in range(4 * n_poses):
            action = follower.next_action(xy, yaw, field)
            if action == Action.STOP or len(poses) >= n_poses:
                break
            if action == Action.MOVE_FORWARD:
                xy, _ = navgrid.move_forward(xy, yaw, env_cfg.forward_step_m)
                forward_steps += 1
            else:
                yaw += follower.turn_rad if action == Action.TURN_LEFT else -follower.turn_rad
            poses.append(camera_pose(xy, yaw, height))
            if forward_steps and forward_steps % look_around_every == 0:
                forward_steps += 1  # look around once per block of steps
                for _ in range(follower.n_headings):
                    if len(poses) >= n_poses:
                        break
                    yaw += follower.turn_rad
                    poses.append(camera_pose(xy, yaw, height))
    return poses


class FollowerHandle:
    """The simulator's privileged handle (``envs.task.SimulatorHandle``) by the
    ``ShortestPathFollower``. It reads the simulator through callables, so one class serves
    calnav's env (``ObjectNavEnv.simulator_handle``) and habitat-lab's ``CalnavSim-v0``:
    ``navgrid()`` and ``env_config()`` at ``reset`` (a new episode may bring a new scene),
    ``pose()`` -> (xy (2,) metres, yaw radians) and ``goal_field()`` (the episode's
    ``GeodesicField``) at every action."""

    def __init__(self, navgrid: Callable[[], Any], env_config: Callable[[], EnvConfig],
                 pose: Callable[[], tuple[np.ndarray, float]], goal_field: Callable[[], Any],
                 layer: Callable[[], int] | None = None):
        self._navgrid, self._env_config, self._pose, self._goal_field = navgrid, env_config, pose, goal_field
        self._layer = layer   # the storey the agent is on (read on a layered grid only)
        self.follower: ShortestPathFollower | None = None

    @property
    def max_episode_steps(self) -> int:
        return int(self._env_config().max_episode_steps)

    def reset(self) -> None:
        self.follower = follower_for(self._navgrid(), self._env_config())

    def shortest_path_action(self) -> Action:
        if self.follower is None:
            raise RuntimeError("the simulator handle was not reset for this episode: call reset() first")
        xy, yaw = self._pose()
        if isinstance(self.follower, LayeredFollower):
            return self.follower.next_action(xy, self._layer(), yaw, self._goal_field())
        return self.follower.next_action(xy, yaw, self._goal_field())


class OracleAgent:
    """Runs the ShortestPathFollower inside an ObjectNavEnv through its privileged handle
    (``simulator_handle``): the env package's own driver, for its tests. calnav's commands run
    ``agent.oracle.OracleAgent`` (the agent registry's ``oracle``), which takes the same
    actions. Interface shared with calnav's agents: reset(obs), act(obs) -> int."""

    name = "oracle"

    def __init__(self, env):
        self.env = env.unwrapped
        self.handle = self.env.simulator_handle()

    def reset(self, obs: dict) -> None:
        self.handle.reset()

    def act(self, obs: dict) -> int:
        e = self.env
        if e.steps >= e.config.max_episode_steps - 1:
            return int(Action.STOP)  # forced STOP on the last step, as PEANUT does
        return int(self.handle.shortest_path_action())
