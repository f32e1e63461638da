"""The agent-env contract (envs/task.py): observation keys and shapes, the gps / compass and
camera conventions, depth normalisation, and the agent's reading of it (agent/sensors.py)."""
import math

import gymnasium as gym
import numpy as np
import pytest

from calnav import envs
from calnav.agent.sensors import SensorModel
from calnav.envs.render import Camera
from calnav.envs.task import (CAMERA_POSE, DEPTH, HABITAT_KEYS, camera_pose, depth_to_metres, gps_compass_to_xy_yaw,
                       normalize_depth_m, observation_specs, pinhole_intrinsics, xy_yaw_to_gps_compass,
                       yaw_to_habitat_quaternion)


def test_gps_compass_hand_computed():
    q = yaw_to_habitat_quaternion
    # start at (1, 2) facing +y; +y is forward, +x is to the right
    gps, compass = xy_yaw_to_gps_compass((1.0, 3.0), math.pi / 2, (1.0, 2.0), q(math.pi / 2))
    np.testing.assert_allclose(gps, [1.0, 0.0], atol=1e-6)
    assert compass[0] == pytest.approx(0.0)
    gps, compass = xy_yaw_to_gps_compass((0.0, 2.0), math.pi, (1.0, 2.0), q(math.pi / 2))
    np.testing.assert_allclose(gps, [0.0, -1.0], atol=1e-6)     # one metre to the left
    assert compass[0] == pytest.approx(math.pi / 2)
    xy, yaw = gps_compass_to_xy_yaw(gps, compass)              # start frame: x forward, y left
    np.testing.assert_allclose(xy, [0.0, 1.0], atol=1e-6)
    assert yaw == pytest.approx(math.pi / 2)
    _, compass = xy_yaw_to_gps_compass((0, 0), -0.1, (0, 0), q(2 * math.pi - 0.2))  # wraps into [-pi, pi]
    assert compass[0] == pytest.approx(0.1, abs=1e-6)
    # facing backwards: habitat-lab's atan2 gives +-pi; either is the same heading
    _, compass = xy_yaw_to_gps_compass((0, 0), 0.3 + math.pi, (0, 0), q(0.3))
    assert abs(compass[0]) == pytest.approx(math.pi)


def test_gps_takes_the_start_position_in_float32():
    """As habitat-lab's EpisodicGPSSensor: the start position is rounded to float32 before the
    difference, so an agent standing exactly at a start of 10.1 m reads 10.1 - float32(10.1)."""
    start = (10.1, 0.0)
    gps, _ = xy_yaw_to_gps_compass(start, 0.0, start, yaw_to_habitat_quaternion(0.0))
    assert gps[0] == np.float32(10.1 - float(np.float32(10.1))) != 0.0 and abs(gps[1]) < 1e-15


def test_pinhole_intrinsics_and_camera_pose_hand_computed():
    k = pinhole_intrinsics(160, 120, 90.0)                    # f = (160 / 2) / tan(45 deg) = 80
    np.testing.assert_allclose(k, [[80, 0, 79.5], [0, 80, 59.5], [0, 0, 1]])
    np.testing.assert_allclose(Camera(160, 120, 90.0).intrinsics, k)   # the renderer uses the contract's
    p = camera_pose((1.0, 2.0), math.pi / 2, 0.88)            # facing +y: right is +x, down is -z
    np.testing.assert_allclose(p[:3, :3], [[1, 0, 0], [0, 0, 1], [0, -1, 0]], atol=1e-12)
    np.testing.assert_allclose(p[:3, 3], [1.0, 2.0, 0.88])


def test_depth_normalisation_hand_computed():
    d = np.array([0.0, 0.5, 2.75, 5.0], np.float32)
    n = normalize_depth_m(d, 0.5, 5.0)
    np.testing.assert_allclose(n, [0.0, 0.0, 0.5, 1.0])
    back = depth_to_metres(n, True, 0.5, 5.0)
    np.testing.assert_allclose(back, [0.0, 0.0, 2.75, 0.0])   # 0 and 1 (missing / too far) are invalid
    assert depth_to_metres(d, False, 0.5, 5.0) is not None and np.array_equal(depth_to_metres(d, False, 0.5, 5.0), d)


def test_env_spaces_follow_the_contract_and_normalise_depth(small_env_config):
    e = gym.make(envs.ENV_ID, split="val", config=small_env_config)
    w, h = small_env_config.resolution
    specs = observation_specs(w, h, 6, 20, small_env_config.max_depth_m, False, True)
    assert set(e.observation_space.spaces) == set(specs)
    for key, spec in specs.items():
        assert e.observation_space[key].shape == spec.shape and e.observation_space[key].dtype == spec.dtype
    obs_m, _ = e.reset(options={"episode_index": 0})
    en = gym.make(envs.ENV_ID, split="val", config=small_env_config, normalize_depth=True)
    obs_n, _ = en.reset(options={"episode_index": 0})
    assert en.observation_space[DEPTH].high.max() == 1.0 and obs_n[DEPTH].max() <= 1.0
    np.testing.assert_allclose(obs_n[DEPTH], normalize_depth_m(obs_m[DEPTH], 0.5, 5.0))
    sensors = SensorModel.from_env_config(en.unwrapped.config)
    valid = (obs_m[DEPTH][..., 0] > 0) & (obs_m[DEPTH][..., 0] < 5.0)
    np.testing.assert_allclose(sensors.depth_m(obs_n)[valid], obs_m[DEPTH][..., 0][valid], rtol=1e-5)


def test_sensor_model_pose_matches_the_simulator_in_the_start_frame(small_env_config):
    """gps + compass + known camera height give the simulator's camera pose moved into the
    start frame (procedural floors are at z = 0)."""
    e = gym.make(envs.ENV_ID, split="val", config=small_env_config).unwrapped
    obs, _ = e.reset(options={"episode_index": 1})
    sensors = SensorModel.from_env_config(e.config)
    for a in (2, 1, 1, 3, 1):
        obs, *_ = e.step(a)
    ep = e.episode
    c, s = math.cos(ep.start_yaw), math.sin(ep.start_yaw)
    start = np.eye(4)                       # world-from-start-frame: z-up, x along the start heading,
    start[:2, :2] = [[c, -s], [s, c]]       # origin on the floor (z = 0) below the start position
    start[:2, 3] = ep.start_position
    expected = np.linalg.inv(start) @ obs[CAMERA_POSE]
    np.testing.assert_allclose(sensors.pose(obs), expected, atol=1e-5)
    np.testing.assert_allclose(sensors.intrinsics, obs["camera_intrinsics"])


def test_sensor_model_errors_are_clear(small_env_config):
    sensors = SensorModel.from_env_config(small_env_config)
    with pytest.raises(KeyError, match="lacks gps, compass"):
        sensors.check({"rgb": 0, "depth": 0, "objectgoal": 0})
    w, h = small_env_config.resolution
    obs = {k: np.zeros(1) for k in HABITAT_KEYS} | {DEPTH: np.zeros((h + 1, w, 1), np.float32)}
    with pytest.raises(ValueError, match="env.resolution"):
        sensors.check(obs)
