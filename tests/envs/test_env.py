"""The gymnasium ObjectNav environment and the oracle: spec, actions, sensors, metrics."""
import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from calnav import envs
from tests.conftest import small_or_full
from calnav.envs.oracle import OracleAgent, ShortestPathFollower
from calnav.envs.semantics import NUM_CLASSES
from calnav.envs.task import Action
from calnav.eval.config import load_config


@pytest.fixture(scope="module")
def env(small_env_config):
    e = gym.make(envs.ENV_ID, split="val", config=small_env_config)
    yield e
    e.close()


def test_registered_and_check_env_passes(small_env_config):
    assert envs.ENV_ID in gym.registry
    e = gym.make(envs.ENV_ID, split="val", config=small_env_config)
    check_env(e.unwrapped, skip_render_check=True)


def test_make_with_defaults_and_overrides(small_env_config):
    e = gym.make(envs.ENV_ID, split="val", config=small_env_config, resolution=(32, 24))
    obs, _ = e.reset(seed=0)
    assert obs["rgb"].shape == (24, 32, 3)
    with pytest.raises(ValueError, match="unknown EnvConfig fields"):
        gym.make(envs.ENV_ID, split="val", config=small_env_config, resolutoin=(32, 24))


def test_make_max_episode_steps_is_the_envs_own_limit(small_env_config):
    """gym.make(max_episode_steps=3): the env itself truncates at 3 (its info and state end the
    episode there), not only gymnasium's outer TimeLimit while the env runs on to 500."""
    from dataclasses import replace

    e = gym.make(envs.ENV_ID, split="val", config=small_env_config, max_episode_steps=3)
    assert e.unwrapped.config.max_episode_steps == 3 and e.spec.max_episode_steps == 3
    assert gym.make(e.spec).unwrapped.config.max_episode_steps == 3  # the spec rebuilds it
    e.reset(options={"episode_index": 0})
    for i in range(3):
        _, _, terminated, truncated, info = e.step(int(Action.TURN_LEFT))
    assert (terminated, truncated, info["steps"]) == (False, True, 3)
    with pytest.raises(RuntimeError, match="episode is over"):
        e.unwrapped.step(int(Action.TURN_LEFT))
    # without the argument the config's limit stands; a config stating another limit contradicts it
    assert gym.make(envs.ENV_ID, split="val", config=small_env_config).unwrapped.config.max_episode_steps == 500
    with pytest.raises(ValueError, match="contradicts the env config's max_episode_steps=7"):
        gym.make(envs.ENV_ID, split="val", config=replace(small_env_config, max_episode_steps=7), max_episode_steps=3)


def test_observation_spec(env, small_env_config):
    obs, info = env.reset(options={"episode_index": 0})
    w, h = small_env_config.resolution
    assert obs["rgb"].shape == (h, w, 3) and obs["rgb"].dtype == np.uint8
    assert obs["depth"].shape == (h, w, 1) and obs["depth"].dtype == np.float32
    valid = obs["depth"][obs["depth"] > 0]
    assert valid.min() >= 0.5 and valid.max() <= 5.0
    assert obs["semantic"].shape == (h, w) and obs["semantic"].max() < NUM_CLASSES
    assert obs["gps"].shape == (2,) and np.allclose(obs["gps"], 0, atol=1e-6)  # float32 start (as Habitat)
    assert obs["compass"].shape == (1,) and obs["compass"][0] == pytest.approx(0.0, abs=1e-6)
    assert obs["objectgoal"][0] == env.unwrapped.episode.goal_id
    pose = obs["camera_pose"]
    assert np.allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-9)
    assert pose[2, 3] == pytest.approx(0.88)
    for key in ("distance_to_goal", "success", "spl", "softspl"):
        assert key in info
    assert info["distance_to_goal"] == pytest.approx(env.unwrapped.episode.geodesic_distance, abs=1e-6)


def test_semantic_sensor_can_be_switched_off(small_env_config):
    e = gym.make(envs.ENV_ID, split="val", config=small_env_config, semantic_sensor=False)
    obs, _ = e.reset(seed=1)
    assert "semantic" not in obs and "semantic" not in e.observation_space.spaces


def test_actions_move_turn_and_gps_compass(env):
    env.reset(options={"episode_index": 0})
    e = env.unwrapped
    assert env.step(Action.TURN_LEFT)[0]["compass"][0] == pytest.approx(math.radians(30), abs=1e-6)
    env.step(Action.TURN_RIGHT)
    assert env.step(Action.TURN_RIGHT)[0]["compass"][0] == pytest.approx(-math.radians(30), abs=1e-6)
    for _ in range(12):  # face a direction with free space ahead
        if e.navgrid.move_forward(e.position, e.yaw, 0.25)[1]:
            break
        env.step(Action.TURN_LEFT)
    p0 = e.position.copy()
    obs, _, _, _, info = env.step(Action.MOVE_FORWARD)
    assert np.linalg.norm(e.position - p0) == pytest.approx(0.25, abs=1e-9)
    heading = obs["compass"][0]  # relative to the start heading, counter-clockwise positive
    # habitat-lab's GPS is (forward, right) in the start frame; the agent started at gps = 0
    assert obs["gps"] == pytest.approx([0.25 * math.cos(heading), -0.25 * math.sin(heading)], abs=1e-5)
    assert info["path_length"] == pytest.approx(0.25, abs=1e-9)


def test_blocked_forward_does_not_move(env):
    env.reset(options={"episode_index": 0})
    e = env.unwrapped
    for _ in range(200):  # walk into a wall
        _, moved = e.navgrid.move_forward(e.position, e.yaw, 0.25)
        if not moved:
            break
        env.step(Action.MOVE_FORWARD)
    p0 = e.position.copy()
    _, _, _, _, info = env.step(Action.MOVE_FORWARD)
    assert np.array_equal(e.position, p0)
    assert info["collisions"] >= 1


def test_invalid_actions_and_step_after_done(env):
    env.reset(options={"episode_index": 0})
    with pytest.raises(ValueError, match="valid actions: 0=STOP, 1=MOVE_FORWARD, 2=TURN_LEFT, 3=TURN_RIGHT"):
        env.step(4)  # LOOK_UP is off by default
    with pytest.raises(ValueError, match="invalid action"):
        env.step(1.5)
    for flag in (True, np.bool_(True), False):   # not MOVE_FORWARD / STOP
        with pytest.raises(ValueError, match="invalid action"):
            env.step(flag)
    _, _, terminated, truncated, info = env.step(Action.STOP)
    assert terminated and not truncated
    with pytest.raises(RuntimeError, match="call reset"):
        env.step(Action.MOVE_FORWARD)


def test_step_limit_truncates(small_env_config):
    e = gym.make(envs.ENV_ID, split="val", config=small_env_config, max_episode_steps=3)
    e.reset(seed=0)
    outs = [e.step(Action.TURN_LEFT) for _ in range(3)]
    assert [o[3] for o in outs] == [False, False, True]
    assert outs[-1][4]["success"] == 0.0


def test_look_actions_when_enabled(small_env_config):
    e = gym.make(envs.ENV_ID, split="val", config=small_env_config, enable_look=True)
    assert e.action_space.n == 6
    obs, _ = e.reset(seed=0)
    obs2 = e.step(Action.LOOK_DOWN)[0]
    forward_z = obs2["camera_pose"][2, 2]  # camera z axis (optical axis), world z component
    assert forward_z == pytest.approx(-math.sin(math.radians(30)), abs=1e-6)


def test_oracle_succeeds_on_every_test_episode():
    """Proves episodes, geodesics and metrics agree: Success 1.0 everywhere and SPL >= 0.9,
    except on episodes where no sequence of Habitat actions can do better: there an exact
    search over the action lattice (1 mm states, unweighted A*) must find no shorter path.
    (With 0.25 m steps and 30 degree turns one extra step costs > 10 % SPL below ~2.5 m.)"""
    cfg = load_config(None, ["env.resolution=32x24", f"env.dataset.test_scenes={small_or_full(3, 30)}",
                             f"env.dataset.episodes_per_scene={small_or_full(5, 20)}"]).env
    e = gym.make(envs.ENV_ID, split="test", config=cfg)
    u = e.unwrapped
    agent = OracleAgent(e)
    spls = []
    for i in range(len(u.episodes)):
        obs, info = e.reset(options={"episode_index": i})
        start, yaw = u.position.copy(), u.yaw
        agent.reset(obs)
        done = False
        while not done:
            obs, _, terminated, truncated, info = e.step(agent.act(obs))
            done = terminated or truncated
        assert info["success"] == 1.0, info
        spls.append(info["spl"])
        if info["spl"] < 0.9:
            exact = ShortestPathFollower(u.navgrid, u.config)._search(start, yaw, u.goal_field, 0.001, 1.0, 400_000)
            assert exact is not None
            optimum_m = sum(a == Action.MOVE_FORWARD for a in exact) * cfg.forward_step_m
            assert info["path_length"] == pytest.approx(optimum_m), (i, info)
    assert np.mean(spls) >= 0.95


def test_same_seed_same_observations(small_env_config):
    a = gym.make(envs.ENV_ID, split="val", config=small_env_config)
    b = gym.make(envs.ENV_ID, split="val", config=small_env_config)
    oa, _ = a.reset(seed=7)
    ob, _ = b.reset(seed=7)
    assert all(np.array_equal(oa[k], ob[k]) for k in oa)


@pytest.mark.parametrize("options, message", [
    ({"episode_index": 1.7}, r"episode_index must be an int.*got 1.7"),
    ({"episode_index": "abc"}, r"episode_index must be an int.*got 'abc'"),
    ({"episode_index": True}, r"episode_index must be an int.*got True"),
    ({"episode_index": -1}, r"episode_index -1 is outside 0:8"),
    ({"episode_index": 8}, r"episode_index 8 is outside 0:8"),
    ([1], r"options must be a dict.*got list"),
    ({"episode": 1}, r"unknown reset option 'episode'; valid options: episode_index, episode_id"),
    ({"episode_index": 1, "episode_id": "x"}, r"either episode_index or episode_id"),
    ({"episode_id": 3}, r"episode_id must be a str"),
    ({"episode_id": "nope:000"}, r"unknown episode_id 'nope:000'"),
])
def test_reset_options_are_validated(env, options, message):
    with pytest.raises(ValueError, match=message):
        env.reset(options=options)


def test_reset_accepts_numpy_integers_and_ids(env):
    import numpy as np

    _, info = env.reset(options={"episode_index": np.int64(1)})
    first = env.unwrapped.episode.episode_id
    env.reset(options={"episode_id": first})
    assert env.unwrapped.episode.episode_id == first
    env.reset(options={})
