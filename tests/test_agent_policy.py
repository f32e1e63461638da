"""The PEANUT-like agent end to end: config wiring, registry, and an episode in a small
generated house with ground-truth segmentation."""
import numpy as np
import pytest

from eval.config import ConfigError, load_config

MAX_STEPS = 200          # the test episode is short: a few metres
NDF_STEPS = 40           # steps of the NDF / uncertainty-aware observation check


def test_agent_config_keys_and_validation():
    cfg = load_config(None, ["agent.map_type=ndf", "agent.goal_threshold=0.9", "agent.segmenter_config.gt_confidence=0.95"])
    assert cfg.agent.map_type == "ndf" and cfg.agent.goal_threshold == 0.9
    assert cfg.agent.segmenter_config.gt_confidence == 0.95
    with pytest.raises(ConfigError, match="map_type"):
        load_config(None, ["agent.map_type=voxels"])
    with pytest.raises(ConfigError, match="goal_threshold"):
        load_config(None, ["agent.goal_threshold=1.5"])


def test_peanut_is_registered_and_the_default():
    from eval.objectnav.agents import AGENTS
    from eval.config import AGENT_NAMES, RunConfig

    assert set(AGENTS) == set(AGENT_NAMES)  # run.agent's choices are exactly the registry's names
    assert RunConfig().agent == "peanut"


@pytest.fixture(scope="module")
def small_setup():
    import gymnasium as gym

    import envs

    cfg = load_config(None, ["env.resolution=160x120", "env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=6",
                             f"env.max_episode_steps={MAX_STEPS}", "agent.map_size_m=24",
                             "mapping.initial_alloc_mb=32", "agent.map_resolution=80x60"])
    env = gym.make(envs.ENV_ID, split="val", config=cfg.env)
    return cfg, env


def test_agent_finds_goal_in_small_house(small_setup):
    from agent.policy import PeanutAgent

    cfg, env = small_setup
    episodes = env.unwrapped.episodes
    index = int(np.argmin([ep.geodesic_distance for ep in episodes]))   # the shortest episode
    agent = PeanutAgent(cfg)
    obs, info = env.reset(options={"episode_index": index})
    agent.reset(obs)
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(agent.act(obs))
        done = terminated or truncated
    assert info["success"], f"episode {index}: distance to goal {info['distance_to_goal']:.2f} m after {info['steps']} steps"
    assert info["steps"] < MAX_STEPS, info["steps"]


def test_agent_reads_only_habitat_observations(small_setup):
    """The same actions from Habitat's keys alone (+ semantic for gt) as from the full
    observation: no decision depends on the privileged camera_pose / camera_intrinsics."""
    from agent.policy import PeanutAgent
    from envs.task import HABITAT_KEYS, SEMANTIC

    cfg, env = small_setup
    episodes = env.unwrapped.episodes
    index = int(np.argmin([ep.geodesic_distance for ep in episodes]))
    full, reduced = PeanutAgent(cfg), PeanutAgent(cfg)
    keep = (*HABITAT_KEYS, SEMANTIC)
    obs, _ = env.reset(options={"episode_index": index})
    full.reset(obs)
    reduced.reset({k: obs[k] for k in keep})
    done, steps = False, 0
    while not done:
        action = full.act(obs)
        assert reduced.act({k: obs[k] for k in keep}) == action, f"step {steps}"
        obs, _, terminated, truncated, _ = env.step(action)
        done, steps = terminated or truncated, steps + 1
    assert steps > cfg.env.turn_angle_deg and full.info.mode == "stop"


def test_ndf_uncertainty_aware_agent_and_video_panel_on_habitat_observations(small_setup):
    """The NDF baseline with the uncertainty-aware variant also reads only Habitat's keys, and
    the video panel draws from such an agent (first NDF_STEPS steps)."""
    import dataclasses

    from agent.policy import PeanutAgent
    from agent.visualize import render_panel
    from envs.task import HABITAT_KEYS, SEMANTIC

    cfg, env = small_setup
    cfg = dataclasses.replace(cfg, agent=dataclasses.replace(cfg.agent, map_type="ndf", uncertainty_aware=True))
    full, reduced = PeanutAgent(cfg), PeanutAgent(cfg)
    keep = (*HABITAT_KEYS, SEMANTIC)
    obs, _ = env.reset(options={"episode_index": 0})
    full.reset(obs)
    reduced.reset({k: obs[k] for k in keep})
    for step in range(NDF_STEPS):
        action = full.act(obs)
        assert reduced.act({k: obs[k] for k in keep}) == action, f"step {step}"
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            break
    panel = render_panel(reduced)
    assert panel.ndim == 3 and panel.shape[2] == 3 and panel.std() > 0
