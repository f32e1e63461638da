"""habitat-lab's simulator interface on calnav's houses: ``CalnavSim-v0``.

Importing this module imports habitat-lab (``common.habitat_import``: stand-ins for the few
habitat-lab modules that need habitat-sim) and registers, in habitat-lab's registry:

- the simulator ``CalnavSim-v0`` (``habitat.simulator.type``), so that ``habitat.Env`` /
  ``habitat.Benchmark`` run habitat-lab's stock ObjectNav-v1 task -- its GPS / Compass /
  ObjectGoal sensors and DistanceToGoal / Success / SPL / SoftSPL measures -- on calnav houses;
- the task actions ``CalnavLookUpAction`` / ``CalnavLookDownAction``: habitat-lab's
  LOOK_UP / LOOK_DOWN rotate habitat-sim's sensor nodes with magnum; these tilt the camera
  through the simulator instead (same ``tilt_angle``, same clamp as calnav's env).

The simulator wraps calnav's own parts: ``envs.scenes`` (houses), ``envs.render`` (Open3D ray
casting), ``envs.navigation`` (grid, MOVE_FORWARD without sliding), ``envs.geodesics``
(distance fields) and ``envs.motion`` (the action arithmetic the gymnasium env uses, so an
agent takes the same path in both). Conventions are habitat-sim's:

- agent state: position (3,) float64 in Habitat's y-up frame (x_h, y_h, z_h) = (x, z, -y),
  metres, at floor level; rotation a ``quaternion.quaternion`` about +y_h (forward is -z_h);
- sensors (habitat-lab's sensor configs, one camera for all): rgb (H, W, 3) uint8; depth
  (H, W, 1) float32 z-depth clipped to [min_depth, max_depth] metres and, with
  ``normalize_depth`` (habitat-lab's default), mapped to [0, 1]; nothing hit reads as 0
  before clipping, as in habitat-sim. semantic (H, W, 1) int32: calnav class ids (-1 void),
  where habitat-sim gives object instance ids (calnav houses have classes, not HM3D's
  semantic annotation);
- ``geodesic_distance(a, [points])``: metres from a to the nearest of the points over calnav's
  navigation grid (the points' grid cells form the goal set, as the env's DistanceToGoal).

Single floor, one agent, no physics (``step_physics`` is a no-op: motion is kinematic).
"""
from __future__ import annotations

import numpy as np

from calnav.common.habitat_import import import_habitat

habitat = import_habitat()

import quaternion  # noqa: E402  (numpy-quaternion: a habitat-lab dependency)
from gym import spaces  # noqa: E402  (habitat-lab's spaces are gym's)
from habitat.config.default import get_agent_config  # noqa: E402
from habitat.core.embodied_task import SimulatorTaskAction  # noqa: E402
from habitat.core.registry import registry  # noqa: E402
from habitat.core.simulator import (AgentState, DepthSensor, RGBSensor, SemanticSensor, SensorSuite,  # noqa: E402
                                    Simulator)
from habitat.sims.habitat_simulator.actions import HabitatSimActions  # noqa: E402

from calnav.envs.config import EnvConfig, require_single_storey  # noqa: E402
from calnav.envs.episode_files import habitat_quaternion_to_yaw  # noqa: E402
from calnav.envs.episodes import view_point_mask  # noqa: E402
from calnav.envs.task import yaw_to_habitat_quaternion  # noqa: E402
from calnav.envs.habitat_config import (check_same_episodes, env_overrides_from_sim, read_descriptor,  # noqa: E402
                                 sensor_configs)
from calnav.envs.motion import apply_action, tilt  # noqa: E402
from calnav.envs.semantics import NUM_CLASSES  # noqa: E402
from calnav.envs.task import Action  # noqa: E402

SIM_NAME = "CalnavSim-v0"
# Rendering range before the depth sensor clips: habitat-sim renders unclipped z-depth, and the
# sensor clips it to [min_depth, max_depth]; nothing indoors is this far, misses render as 0.
RAW_MAX_DEPTH_M = 1.0e4


def _sim_action(action) -> Action:
    """habitat-sim's discrete action (HabitatSimActions id or name) -> calnav's Action."""
    names = {HabitatSimActions.move_forward: Action.MOVE_FORWARD, HabitatSimActions.turn_left: Action.TURN_LEFT,
             HabitatSimActions.turn_right: Action.TURN_RIGHT}
    if isinstance(action, str) and HabitatSimActions.has_action(action):
        action = HabitatSimActions[action]
    if action not in names:
        raise ValueError(f"CalnavSim-v0 cannot take action {action!r}; valid: None (stay), "
                         f"{', '.join(f'{int(k)}={v.name}' for k, v in names.items())}")
    return names[action]


# ------------------------------------------------------------------------------- sensors
class CalnavRGBSensor(RGBSensor):
    """habitat-sim's RGB camera: (H, W, 3) uint8."""

    def __init__(self, config):
        super().__init__(config=config)

    def _get_observation_space(self, *args, **kwargs):
        return spaces.Box(0, 255, (self.config.height, self.config.width, 3), np.uint8)

    def get_observation(self, sim_obs):
        return sim_obs["rgb"]


class CalnavDepthSensor(DepthSensor):
    """habitat-sim's depth camera: z-depth clipped to [min_depth, max_depth] metres, then
    (normalize_depth) (d - min) / (max - min); (H, W, 1) float32."""

    def __init__(self, config):
        self.min_depth, self.max_depth = float(config.min_depth), float(config.max_depth)
        self.normalize = bool(config.normalize_depth)
        super().__init__(config=config)

    def _get_observation_space(self, *args, **kwargs):
        shape = (self.config.height, self.config.width, 1)
        if self.normalize:
            return spaces.Box(0.0, 1.0, shape, np.float32)
        return spaces.Box(self.min_depth, self.max_depth, shape, np.float32)

    def get_observation(self, sim_obs):
        d = np.clip(sim_obs["depth"], np.float32(self.min_depth), np.float32(self.max_depth))[..., None]
        if self.normalize:
            d = (d - np.float32(self.min_depth)) / np.float32(self.max_depth - self.min_depth)
        return d.astype(np.float32)


class CalnavSemanticSensor(SemanticSensor):
    """(H, W, 1) int32 calnav class ids, -1 void (habitat-sim: instance ids)."""

    def __init__(self, config):
        super().__init__(config=config)

    def _get_observation_space(self, *args, **kwargs):
        return spaces.Box(-1, NUM_CLASSES - 1, (self.config.height, self.config.width, 1), np.int32)

    def get_observation(self, sim_obs):
        return sim_obs["semantic"][..., None].astype(np.int32)


SENSOR_CLASSES = {"rgb": CalnavRGBSensor, "depth": CalnavDepthSensor, "semantic": CalnavSemanticSensor}


# ------------------------------------------------------------------------------- simulator
@registry.register_simulator(name=SIM_NAME)
class CalnavSim(Simulator):
    """habitat-lab ``Simulator`` over calnav houses (see the module docstring)."""

    def __init__(self, config) -> None:
        self.habitat_config = config
        self._sensor_kinds = sensor_configs(config)
        self._sensor_suite = SensorSuite([SENSOR_CLASSES[k](c) for k, c in self._sensor_kinds.items()])
        self.env_config: EnvConfig | None = None
        self.scene_id: str | None = None
        self._scene_key: tuple | None = None
        self.position = np.zeros(2)
        self.yaw = self.pitch = 0.0
        self.floor_y = 0.0
        self._collided = False

    # ---------------------------------------------------------------- habitat API
    @property
    def sensor_suite(self) -> SensorSuite:
        return self._sensor_suite

    @property
    def action_space(self):
        return spaces.Discrete(len(HabitatSimActions))

    @property
    def previous_step_collided(self) -> bool:
        return self._collided

    def reconfigure(self, habitat_config, ep_info=None, should_close_on_new_scene: bool = True) -> None:
        """Load ``habitat_config.scene`` (``<calnav split dir>/<scene id>``) and place the agent
        at the agent config's start state (set from the episode by habitat-lab's task)."""
        self.habitat_config = habitat_config
        episodes_env, scene_id = read_descriptor(habitat_config.scene)
        from dataclasses import replace

        env = replace(episodes_env, **env_overrides_from_sim(habitat_config))
        check_same_episodes(episodes_env, env, f"scene {habitat_config.scene}")
        key = (habitat_config.scene, env)
        if key != self._scene_key:
            self._load_scene(scene_id, env)
            self._scene_key = key
        agent = get_agent_config(habitat_config)
        if agent.is_set_start_state:
            p = np.asarray(agent.start_position, np.float64)
            self._start = (np.array([p[0], -p[2]]), habitat_quaternion_to_yaw(list(agent.start_rotation)), float(p[1]))
        else:  # no episode: the first navigable cell, facing +x
            self._start = (self.navgrid.to_world(np.argwhere(self.navgrid.navigable)[0]), 0.0, 0.0)

    def _load_scene(self, scene_id: str, env: EnvConfig) -> None:
        from calnav.envs.navigation import NavGrid
        from calnav.envs.render import Camera, Renderer
        from calnav.envs.scenes import load_scene

        require_single_storey(env, "habitat-lab's CalnavSim-v0")
        self.scene = load_scene(scene_id, env.dataset)
        self.camera = Camera.from_config(env)
        self.renderer = Renderer(self.scene, self.camera, min_depth_m=0.0, max_depth_m=RAW_MAX_DEPTH_M)
        self.navgrid = NavGrid.build(self.scene, env, self.renderer.raycasting_scene)
        self.env_config, self.scene_id = env, scene_id

    def reset(self):
        self.position, self.yaw, self.floor_y = self._start[0].copy(), self._start[1], self._start[2]
        self.pitch = 0.0
        self._collided = False
        return self.get_sensor_observations()

    def step(self, action, *args, **kwargs):
        """One habitat-sim action (move_forward / turn_left / turn_right); None stays (what
        habitat-lab's task asks after STOP or a look action)."""
        self._collided = False
        if action is not None:
            a = _sim_action(action)
            self.position, self.yaw, self.pitch, self._collided = apply_action(
                self.navgrid, self.env_config, self.position, self.yaw, self.pitch, a)
        return self.get_sensor_observations()

    def tilt_camera(self, degrees: float) -> None:
        """Tilt the camera by ``degrees`` (positive up); the look actions' effect."""
        self.pitch = tilt(self.pitch, degrees)
        self._collided = False

    def step_physics(self, dt: float) -> None:
        """No physics: motion is kinematic."""

    def seed(self, seed: int) -> None:
        """Nothing is random in the simulator (no sensor noise)."""

    def close(self, destroy: bool = True) -> None:
        self._scene_key = None

    def get_agent_state(self, agent_id: int = 0) -> AgentState:
        if agent_id != 0:
            raise ValueError(f"CalnavSim-v0 has one agent (id 0), got agent_id={agent_id}")
        x, y, z, w = yaw_to_habitat_quaternion(self.yaw)
        return AgentState(position=np.array([self.position[0], self.floor_y, -self.position[1]], np.float64),
                          rotation=quaternion.quaternion(w, x, y, z))

    def geodesic_distance(self, position_a, position_b, episode=None) -> float:
        """Metres from ``position_a`` ((3,) Habitat frame) to the nearest of ``position_b``
        (one (3,) point or a list of them) over the navigation grid; inf if unreachable."""
        return float(self.goal_field(position_b).distance(_xy(position_a)))

    def goal_field(self, points):
        """The navigation grid's distance field to the cells of ``points`` (Habitat frame)."""
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        return self.navgrid.geodesic_field(view_point_mask(self.navgrid, _xy(pts)))

    def get_sensor_observations(self):
        from calnav.envs.render import camera_pose

        z = self.navgrid.floor_height(self.position) + self.env_config.camera_height_m   # standing on the navmesh
        pose = camera_pose(self.position, self.yaw, z, self.pitch)
        frame = self.renderer.render(pose)
        self.last_instances = frame.instance   # (H, W) instance ids of the last frame (what is in view)
        sim_obs = {"rgb": frame.rgb, "depth": frame.depth, "semantic": frame.semantic}
        return self._sensor_suite.get_observations(sim_obs)


def _xy(p) -> np.ndarray:
    """Habitat y-up point(s) (..., 3) -> calnav world xy (..., 2) float64."""
    p = np.asarray(p, np.float64)
    return np.stack([p[..., 0], -p[..., 2]], axis=-1)


# ------------------------------------------------------------------------------- look actions
class _CalnavLook(SimulatorTaskAction):
    """Tilt the camera by ``sign * config.tilt_angle`` degrees through the simulator; returns
    None, so the task reads the observations with ``sim.step(None)`` (as for the stock actions)."""

    sign = 1.0

    def step(self, *args, **kwargs):
        self._sim.tilt_camera(self.sign * float(self._config.tilt_angle))


@registry.register_task_action
class CalnavLookUpAction(_CalnavLook):
    sign = 1.0


@registry.register_task_action
class CalnavLookDownAction(_CalnavLook):
    sign = -1.0


def registered() -> bool:
    """Whether CalnavSim-v0 is in habitat-lab's registry (true once this module is imported)."""
    return registry.get_simulator(SIM_NAME) is CalnavSim

