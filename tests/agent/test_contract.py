"""The agent's contract (agent/contract.py): the Habitat observation its parts read, the
privileged part that reaches only the parts declaring it, and the agent registry handing the
simulator's privileged handle only to the agent class that declares it (the oracle)."""
from dataclasses import fields

import numpy as np
import pytest

from calnav.agent.contract import (INSTANCE, OBSERVED_PRIVILEGED, SIMULATOR, Observation, Privileged,
                                   declared_privileged, handed, split_observation)
from calnav.envs.task import CAMERA_INTRINSICS, CAMERA_POSE, HABITAT_KEYS, SEMANTIC

W, H = 32, 24


def _env_obs(semantic: bool = True) -> dict:
    obs = {"rgb": np.zeros((H, W, 3), np.uint8), "depth": np.ones((H, W, 1), np.float32),
           "gps": np.zeros(2, np.float32), "compass": np.zeros(1, np.float32), "objectgoal": np.array([0]),
           CAMERA_POSE: np.eye(4), CAMERA_INTRINSICS: np.eye(3), INSTANCE: np.zeros((H, W), np.int32)}
    if semantic:
        obs[SEMANTIC] = np.zeros((H, W), np.int16)
    return obs


def test_the_typed_observation_holds_habitats_keys_and_nothing_privileged():
    assert tuple(f.name for f in fields(Observation)) == (*HABITAT_KEYS, SEMANTIC)
    assert tuple(f.name for f in fields(Privileged)) == OBSERVED_PRIVILEGED
    env_obs = _env_obs()
    observation, privileged = split_observation(env_obs)
    assert list(observation) == [*HABITAT_KEYS, SEMANTIC]
    assert all(observation[k] is env_obs[k] for k in observation)          # the env's arrays, not copies
    for key in (CAMERA_POSE, CAMERA_INTRINSICS, INSTANCE):
        assert key not in observation
        with pytest.raises(KeyError):
            observation[key]
    assert privileged.camera_pose is env_obs[CAMERA_POSE] and privileged.instance is env_obs[INSTANCE]
    observation, _ = split_observation(_env_obs(semantic=False))
    assert SEMANTIC not in observation and len(observation) == len(HABITAT_KEYS)
    with pytest.raises(KeyError, match="observation lacks gps, which an ObjectNav agent needs"):
        split_observation({k: v for k, v in env_obs.items() if k != "gps"})


def test_a_part_is_handed_only_the_privileged_data_its_class_declares():
    from calnav.agent.segmenters.ground_truth import GroundTruthSegmenter
    from calnav.agent.segmenters.noisy import NoisySegmenter

    _, privileged = split_observation(_env_obs())
    assert declared_privileged(NoisySegmenter) == (CAMERA_POSE, INSTANCE)
    assert declared_privileged(GroundTruthSegmenter) == ()
    given = handed(NoisySegmenter, privileged)
    assert given.camera_pose is privileged.camera_pose and given.camera_intrinsics is None
    assert handed(GroundTruthSegmenter, privileged) == Privileged()

    class Typo:
        privileged = ("camera_pos",)

    with pytest.raises(ValueError, match="Typo declares unknown privileged data 'camera_pos'; valid: camera_pose"):
        handed(Typo(), privileged)

    class Instance:
        privileged = ()

    part = Instance()
    part.privileged = (CAMERA_POSE,)   # only the class's declaration counts
    assert handed(part, privileged) == Privileged()


class _Recorder:
    """A segmenter that records the keyword inputs perception hands it."""

    name, needs_semantic, class_names = "recorder", True, ("a", "b")
    num_classes = 2

    def __init__(self):
        self.given: dict = {}

    def __call__(self, rgb, depth, **kwargs):
        self.given = kwargs
        return np.zeros((*depth.shape, 2), np.float32)


class _PoseRecorder(_Recorder):
    privileged = (CAMERA_POSE,)


@pytest.mark.parametrize("segmenter, expected", [(_Recorder, {"semantic"}), (_PoseRecorder, {"semantic", "pose"})])
def test_perception_hands_the_segmenter_what_it_declares(segmenter, expected):
    from calnav.agent.perception import Perception
    from calnav.agent.sensors import SensorModel
    from calnav.eval.config import load_config

    cfg = load_config(None, [f"env.resolution={W}x{H}", f"agent.map_resolution={W}x{H}"])
    perception = Perception(cfg.agent, cfg.segmenter, SensorModel.from_env_config(cfg.env))
    perception.segmenter = seg = segmenter()
    observation, privileged = split_observation(_env_obs())
    perception.observe(observation, privileged)
    assert set(seg.given) == expected
    if "pose" in expected:
        np.testing.assert_array_equal(seg.given["pose"], np.eye(4))
    perception.observe(observation)                # no privileged part: nothing privileged handed
    assert set(seg.given) == {"semantic"}


def test_build_agent_hands_the_simulator_only_to_an_agent_declaring_it(monkeypatch):
    from calnav.agent.oracle import OracleAgent
    from calnav.agent.policy import PeanutAgent
    from calnav.agent.setup import build_agent
    from calnav.eval.config import agent_setup, load_config

    cfg = load_config(None, [])
    handle = object()
    assert declared_privileged(OracleAgent) == (SIMULATOR,) and declared_privileged(PeanutAgent) == ()
    oracle = build_agent(agent_setup(cfg, "oracle"), simulator=handle)
    assert isinstance(oracle, OracleAgent) and oracle.simulator is handle
    with pytest.raises(ValueError, match="agent 'oracle' needs the simulator's privileged handle"):
        build_agent(agent_setup(cfg, "oracle"))
    monkeypatch.setattr(PeanutAgent, "from_setup", classmethod(lambda cls, setup_, **handed_: handed_))
    assert build_agent(agent_setup(cfg, "peanut"), simulator=handle) == {}     # built without the handle


def test_the_registered_oracle_takes_the_env_oracles_actions(small_env_config):
    """The registry's oracle (through the env's privileged handle, counting its own steps)
    takes the same actions as the env package's driver, STOP on the last step included."""
    import dataclasses

    import gymnasium as gym

    from calnav import envs
    from calnav.agent.setup import build_agent
    from calnav.envs.oracle import OracleAgent as EnvOracle
    from calnav.eval.config import agent_setup, load_config

    for limit in (500, 6):   # to the goal; cut short: the forced STOP on step 6
        env_cfg = dataclasses.replace(small_env_config, max_episode_steps=limit)
        env = gym.make(envs.ENV_ID, split="val", config=env_cfg)
        ours = build_agent(agent_setup(load_config(None, []), "oracle"), simulator=env.unwrapped.simulator_handle())
        theirs = EnvOracle(env)
        obs, _ = env.reset(options={"episode_index": 1})
        ours.reset(obs)
        theirs.reset(obs)
        done, actions = False, []
        while not done:
            action = ours.act(obs).action
            assert action == theirs.act(obs), len(actions)
            actions.append(action)
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        assert actions[-1] == 0 and (info["success"] == 1.0 if limit == 500 else len(actions) == limit)
