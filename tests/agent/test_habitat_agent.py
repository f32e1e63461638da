"""The calnav agent as a ``habitat.Agent`` (``agent/habitat_agent.py``): action names, the
observation conversion against calnav's env, and a run through ``habitat.Benchmark``.

Needs habitat-lab (``.venv-habitat``) and PeanutAgent reading only Habitat's observation keys
(``agent.sensors``, ``envs.task.HABITAT_KEYS``); without them the module is skipped, saying so.
"""

import numpy as np
import pytest

from tests.conftest import assert_same_records, read_records, require_habitat

require_habitat()

from calnav.envs.task import Action, depth_to_metres  # noqa: E402
from calnav.eval.cli import main  # noqa: E402
from calnav.eval.config import agent_setup, load_config  # noqa: E402

pytestmark = pytest.mark.habitat

W, H = 64, 48
SENSORS = "habitat.simulator.agents.main_agent.sim_sensors"
HABITAT_SMALL = [f"{SENSORS}.{s}.{k}={v}" for s in ("rgb_sensor", "depth_sensor", "semantic_sensor")
                 for k, v in (("width", W), ("height", H))]
CALNAV_SMALL = ["env.dataset.val_scenes=2", "env.dataset.episodes_per_scene=3"]
SEMANTIC_CONFIG = "configs/habitat_objectnav_semantic.yaml"


@pytest.fixture(scope="module")
def setup():
    from calnav.envs.habitat_config import HABITAT_CONFIG, habitat_config

    base = load_config(None, CALNAV_SMALL).env
    path = HABITAT_CONFIG.replace("habitat_objectnav.yaml", "habitat_objectnav_semantic.yaml")
    return habitat_config(base, HABITAT_SMALL, config_path=path, progress=False)


def test_action_names_are_the_habitat_tasks(setup):
    from calnav.agent.habitat_agent import habitat_action

    hcfg, _ = setup
    task_actions = list(hcfg.habitat.task.actions)
    for a in Action:
        assert task_actions[int(a)] == habitat_action(a)  # same id, same name


def test_converted_observations_are_calnavs(setup):
    """Along a scripted walk, the wrapper's view of habitat-lab's observations equals calnav's
    env (with Habitat's depth normalisation): rgb, semantic, goal, metric depth, gps and compass
    exactly."""
    import gymnasium as gym

    import calnav.envs  # noqa: F401
    import calnav.envs.habitat_sim_backend  # noqa: F401
    from calnav.agent.habitat_agent import from_habitat_observations, habitat
    from calnav.envs.task import HABITAT_KEYS, SEMANTIC

    hcfg, env_cfg = setup
    assert env_cfg.normalize_depth and env_cfg.semantic_sensor
    henv = habitat.Env(config=hcfg)
    henv.episodes = [henv.episodes[2]]
    cenv = gym.make("calnav/ObjectNav-v0", split="val", config=env_cfg).unwrapped
    cobs, _ = cenv.reset(options={"episode_index": 2})
    hobs = henv.reset()
    lo, hi = env_cfg.min_depth_m, env_cfg.max_depth_m
    for a in [None] + [Action.TURN_LEFT] * 3 + [Action.MOVE_FORWARD] * 6 + [Action.TURN_RIGHT] * 2:
        if a is not None:
            cobs, *_ = cenv.step(int(a))
            hobs = henv.step(a.name.lower())
        obs = from_habitat_observations(hobs)
        assert set(obs) == {*HABITAT_KEYS, SEMANTIC}
        for k in ("rgb", "objectgoal", SEMANTIC):
            assert np.array_equal(obs[k], cobs[k]), k
        assert np.array_equal(depth_to_metres(obs["depth"], True, lo, hi), depth_to_metres(cobs["depth"], True, lo, hi))
        assert np.array_equal(obs["gps"], cobs["gps"]) and np.array_equal(obs["compass"], cobs["compass"])
    henv.close()


def test_reset_waits_for_the_first_observations(setup):
    from calnav.agent.habitat_agent import HabitatPeanutAgent

    hcfg, env_cfg = setup
    cfg = load_config(None, ["agent.segmenter=gt"])
    cfg.env = env_cfg
    agent = HabitatPeanutAgent(agent_setup(cfg))
    agent.reset()
    assert agent.decision is None and agent.navigator.goal is None  # nothing known before the first observations
    obs = {"rgb": np.zeros((H, W, 3), np.uint8), "depth": np.zeros((H, W, 1), np.float32),
           "gps": np.zeros(2, np.float32), "compass": np.zeros(1, np.float32), "objectgoal": np.array([2]),
           "semantic": -np.ones((H, W, 1), np.int32)}
    assert agent.act(obs) == {"action": "turn_left"}  # the opening spin
    goals = agent.navigator.goal_categories
    assert agent.navigator.goal == goals[2] and agent.decision.step == agent.decision.agent_step.steps == 1
    agent.reset()
    agent.act({**obs, "objectgoal": np.array([4])})
    assert agent.navigator.goal == goals[4] and agent.decision.agent_step.steps == 1  # a fresh episode


def test_peanut_through_habitat_benchmark_equals_objectnav(tmp_path, capsys):
    """The PEANUT-like agent through habitat-lab's episode loop takes the same actions as in
    ``calnav objectnav``: every per-episode record is equal (only the wall time differs)."""
    out = tmp_path / "hab"
    assert main(["habitat-benchmark", "--habitat-config", SEMANTIC_CONFIG, "--agent", "peanut", "--episodes", "0:2",
                 "--output", str(out), "agent.segmenter=gt", "run.workers=1", *CALNAV_SMALL, *HABITAT_SMALL]) == 0
    assert "| peanut (gt + averaging) (habitat-lab) |" in capsys.readouterr().out   # what it maps from
    assert main(["objectnav", "--agent", "peanut", "--episodes", "0:2", "--output", str(tmp_path / "cal"),
                 "agent.segmenter=gt", "run.workers=1", f"env.resolution={W}x{H}", "env.normalize_depth=true",
                 *CALNAV_SMALL]) == 0
    hab, cal = read_records(out), read_records(tmp_path / "cal")
    assert sorted(hab) == sorted(cal) == [0, 1] and all(r["status"] == "ok" for r in hab.values())
    assert all(r["steps"] > 12 for r in hab.values())  # the opening spin (12 turns) and then some
    assert_same_records(hab, cal, 1e-5)


def test_a_plugged_in_segmenter_through_habitat_benchmark(tmp_path):
    """A segmenter given by import path runs under habitat-lab's benchmark loop (the plugin wraps
    learned_rgb: its records equal the built-in's there)."""
    base = ["habitat-benchmark", "--agent", "peanut", "--episodes", "0:1", "run.workers=1", *CALNAV_SMALL,
            *HABITAT_SMALL[:4]]   # rgb and depth sensors of the default (semantic-free) config
    assert main([*base, "--output", str(tmp_path / "plugin"),
                 "agent.segmenter=tests.agent.segmenter_plugins:wrapped_learned_rgb"]) == 0
    assert main([*base, "--output", str(tmp_path / "builtin"), "agent.segmenter=learned_rgb"]) == 0
    plugin = read_records(tmp_path / "plugin")
    assert plugin[0]["status"] == "ok"
    assert_same_records(plugin, read_records(tmp_path / "builtin"), 1e-9)
