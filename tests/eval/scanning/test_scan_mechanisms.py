"""What made a real scan hard, rebuilt in test worlds and run end to end: a sofa behind a 3.5 cm
floor step with a hole beside it, and a warped, half-unlabelled floor. Every generated episode
is solved by the oracle; the agent (ground-truth semantics) stops at the sofa and at the bed,
and never stands at the goal, in view, without stopping."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from calnav.eval.config import agent_setup
from tests.conftest import small_or_full

pytestmark = pytest.mark.e2e

EPISODES = small_or_full(4, 12)      # per scene
MAX_STEPS = 300


@pytest.fixture(scope="module")
def scan_worlds(tmp_path_factory):
    from calnav import envs
    from calnav.eval.config import load_config
    from tests.envs.worlds import sofa_step_house, warped_floor_house

    root = tmp_path_factory.mktemp("scan_worlds")
    for scene in (sofa_step_house(), warped_floor_house()):
        scene.save(root / f"{scene.name}.npz")
    cfg = load_config(None, [f"env.dataset.scene_dir={root}", "env.resolution=160x120",
                             f"env.dataset.episodes_per_scene={EPISODES}", f"env.max_episode_steps={MAX_STEPS}",
                             "env.dataset.min_geodesic_m=1.0", "agent.map_size_m=16", "agent.map_resolution=80x60",
                             "mapping.initial_alloc_mb=32"])
    return cfg, gym.make(envs.ENV_ID, split="val", config=cfg.env)


def _run(env, agent, index: int, action_of=int) -> dict:
    """Episode ``index`` driven by ``agent``; ``action_of``: the action id of what its ``act``
    returns (the env's oracle an id, a registry agent an ``agent.step.Step``)."""
    obs, info = env.reset(options={"episode_index": index})
    agent.reset(obs)
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(action_of(agent.act(obs)))
        done = terminated or truncated
    return info


def test_generated_episodes_are_all_solved_by_the_oracle(scan_worlds):
    from calnav.envs.episodes import generation_report
    from calnav.envs.oracle import OracleAgent

    cfg, env = scan_worlds
    eps = env.unwrapped.episodes
    assert {e.scene_id for e in eps} == {"sofa_step_house", "warped_floor_house"}
    report = generation_report("val", cfg.env)
    assert set(report) == {"sofa_step_house", "warped_floor_house"}
    for counts in report.values():
        assert counts["kept"] == EPISODES and counts["drawn"] == counts["kept"] + counts["unsolvable"]
    oracle = OracleAgent(env)
    results = [_run(env, oracle, i) for i in range(len(eps))]
    assert all(r["success"] == 1.0 for r in results), [r["distance_to_goal"] for r in results]


@pytest.mark.parametrize("category", ["sofa", "bed"])
def test_the_agent_finishes_its_approach(scan_worlds, category):
    """Ground-truth semantics: every episode to the sofa (behind the step, beside the hole) and
    to the bed (on the warped floor) ends with a STOP on a view point, and the agent never
    lingers at the goal (more than 20 steps there, in view, without STOP)."""
    from calnav.agent.policy import PeanutAgent
    from calnav.eval.stats import LINGER_STEPS

    cfg, env = scan_worlds
    agent = PeanutAgent(agent_setup(cfg))
    indices = [i for i, e in enumerate(env.unwrapped.episodes) if e.object_category == category]
    assert indices, f"no {category} episode"
    for i in indices:
        info = _run(env, agent, i, lambda step: step.action)
        assert info["success"] == 1.0, (i, info["distance_to_goal"], info["steps"], agent.info.mode)
        assert info["steps_at_goal"] <= LINGER_STEPS, (i, info["steps_at_goal"])
        assert np.isfinite(info["spl"])
