"""The agent's typed setup (``agent.setup.AgentSetup``): one function makes it from the root
config, a robot program makes it without ``calnav.eval``, each part is validated where it is
made and a worker gets it as it is, not rebuilt and validated again."""
import pickle
import subprocess
import sys

import pytest

from calnav.agent.setup import AgentSetup, SensorSetup
from calnav.eval.config import agent_setup, load_config


def test_the_config_becomes_the_setup_in_one_place():
    cfg = load_config(None, ["env.resolution=160x120", "env.turn_angle_deg=15", "env.dataset.storeys=2",
                             "mapping.fusion=glfs", "run.agent=oracle", "run.device=cuda:1"])
    setup = agent_setup(cfg)
    assert setup.agent is cfg.agent and setup.mapping is cfg.mapping and setup.segmenter is cfg.segmenter
    assert (setup.name, setup.device) == ("oracle", "cuda:1") and agent_setup(cfg, "peanut").name == "peanut"
    assert (setup.sensor.resolution, setup.sensor.turn_angle_deg, setup.sensor.storeys) == ((160, 120), 15.0, 2)
    assert agent_setup(load_config(None, [])).sensor == SensorSetup()   # its defaults are the env's


def test_a_bad_sensor_fact_is_one_line_where_it_is_made():
    with pytest.raises(ValueError, match=r"^sensor.hfov_deg must be in \(0, 180\) degrees, got 0$"):
        SensorSetup(hfov_deg=0)
    with pytest.raises(ValueError, match=r"^sensor.max_depth_m must be finite and above min_depth_m >= 0 metres, "
                                         r"got 0.5$"):
        SensorSetup(min_depth_m=0.5, max_depth_m=0.5)
    with pytest.raises(ValueError, match=r"^unknown agent 'nope' for run.agent; valid choices: peanut, oracle$"):
        AgentSetup(name="nope")


def test_a_worker_gets_the_setup_as_it_is(monkeypatch):
    """An episode task pickles the typed config and setup: the worker validates nothing again."""
    from calnav.eval.objectnav.run import EpisodeTask
    from calnav.mapping.config import MappingConfig

    cfg = load_config(None, ["mapping.fusion=glfs"])
    task = EpisodeTask(0, cfg, agent_setup(cfg), 3)
    data = pickle.dumps(task)
    monkeypatch.setattr(MappingConfig, "__post_init__", lambda self: pytest.fail("validated again"))
    got = pickle.loads(data)
    assert got.setup == task.setup and got.setup.mapping.fusion == "glfs" and got.cfg.mapping == cfg.mapping


def test_a_robot_builds_the_agent_without_calnav_eval():
    code = """
import sys
from calnav.agent.config import AgentConfig
from calnav.agent.navigator import Navigator
from calnav.agent.setup import AgentSetup, SensorSetup

nav = Navigator(AgentSetup(agent=AgentConfig(segmenter="gt"), sensor=SensorSetup(resolution=(160, 120))))
nav.reset("chair")
assert not [m for m in sys.modules if m.startswith("calnav.eval")], "calnav.eval was imported"
print(nav.agent_name, nav.goal)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["peanut", "chair"]
