"""habitat-lab interop, checked with habitat-lab's own code: calnav's episode files load with
``ObjectNavDatasetV1``; habitat-lab's stock ObjectNav task, sensors and measures on
``CalnavSim-v0`` agree with calnav's env; ``calnav habitat-benchmark`` agrees with
``calnav objectnav``; bad input. Needs habitat-lab (``.venv-habitat``, ``make test`` runs it).
"""
import json
import math
import os
from dataclasses import replace

import numpy as np
import pytest

from tests.conftest import assert_same_records, read_records, require_habitat

require_habitat()

from calnav.envs.task import Action  # noqa: E402
from calnav.eval.cli import main  # noqa: E402
from calnav.eval.config import load_config  # noqa: E402

pytestmark = pytest.mark.habitat

W, H = 64, 48
SENSORS = "habitat.simulator.agents.main_agent.sim_sensors"
HABITAT_SMALL = [f"{SENSORS}.{s}.{k}={v}" for s in ("rgb_sensor", "depth_sensor") for k, v in (("width", W), ("height", H))]
CALNAV_SMALL = ["env.dataset.val_scenes=2", "env.dataset.episodes_per_scene=3"]
TOL = 1e-5  # habitat-lab's measures vs calnav's (float32 GPS origin, 3D vs 2D norms)
# a scripted episode: turns, a look up and down, walking into a wall (collisions), then STOP
SCRIPT = ([Action.TURN_LEFT] * 2 + [Action.LOOK_UP, Action.LOOK_DOWN, Action.LOOK_DOWN] + [Action.MOVE_FORWARD] * 30
          + [Action.TURN_RIGHT] * 3 + [Action.MOVE_FORWARD] * 5 + [Action.STOP])


@pytest.fixture(scope="module")
def setup():
    """(habitat config, calnav EnvConfig, calnav episodes) of the small val split."""
    from calnav.envs.episodes import load_split
    from calnav.envs.habitat_config import habitat_config

    base = load_config(None, CALNAV_SMALL).env
    hcfg, env = habitat_config(base, HABITAT_SMALL, progress=False)
    return hcfg, env, load_split("val", env, progress=False)


def _habitat_env(hcfg):
    import calnav.envs.habitat_sim_backend  # noqa: F401  (registers CalnavSim-v0)
    from calnav.common.habitat_import import import_habitat

    return import_habitat().Env(config=hcfg)


def test_env_config_follows_the_habitat_config(setup):
    hcfg, env, _ = setup
    assert env.resolution == (W, H) and env.hfov_deg == 79 and env.camera_height_m == 0.88
    assert (env.min_depth_m, env.max_depth_m, env.normalize_depth) == (0.5, 5.0, True)
    assert (env.turn_angle_deg, env.tilt_angle_deg, env.forward_step_m) == (30, 30, 0.25)
    assert (env.agent_radius_m, env.agent_height_m, env.max_episode_steps, env.success_distance_m) == (0.18, 0.88, 500, 0.1)
    assert env.enable_look and not env.semantic_sensor and env.dataset.val_scenes == 2


@pytest.mark.parametrize("name", ["habitat_objectnav.yaml", "habitat_objectnav_semantic.yaml"])
def test_shipped_habitat_configs_compose(name):
    """Each extends habitat-lab's HM3D ObjectNav benchmark config: its values, calnav's simulator."""
    from calnav.common.habitat_import import import_habitat
    from calnav.envs.habitat_config import HABITAT_CONFIG

    cfg = import_habitat().get_config(HABITAT_CONFIG.replace("habitat_objectnav.yaml", name)).habitat
    sensors = cfg.simulator.agents.main_agent.sim_sensors
    assert cfg.simulator.type == "CalnavSim-v0" and cfg.task.type == "ObjectNav-v1"
    assert cfg.simulator.turn_angle == 30 and cfg.environment.max_episode_steps == 500
    assert sensors.rgb_sensor.width == 640 and sensors.depth_sensor.max_depth == 5.0
    assert ("semantic_sensor" in sensors) == name.endswith("_semantic.yaml")
    if "semantic_sensor" in sensors:
        assert (sensors.semantic_sensor.width, sensors.semantic_sensor.hfov) == (640, 79)
    assert cfg.task.actions.look_up.type == "CalnavLookUpAction"


def test_episode_files_load_with_objectnav_dataset_v1(setup):
    from habitat.datasets.object_nav.object_nav_dataset import ObjectNavDatasetV1

    from calnav.envs.episode_files import habitat_quaternion_to_yaw
    from calnav.envs.semantics import GOAL_CATEGORIES

    hcfg, _, calnav = setup
    ds = ObjectNavDatasetV1(hcfg.habitat.dataset)
    assert len(ds.episodes) == len(calnav) == 6
    assert ds.category_to_task_category_id == {c: i for i, c in enumerate(GOAL_CATEGORIES)}
    for h, c in zip(ds.episodes, calnav):
        assert os.path.basename(h.scene_id) == c.scene_id and h.object_category == c.object_category
        assert h.start_position == [c.start_position[0], 0.0, -c.start_position[1]]
        assert math.isclose(habitat_quaternion_to_yaw(h.start_rotation), c.start_yaw, abs_tol=1e-12)
        vps = np.array([v.agent_state.position for g in h.goals for v in g.view_points])
        assert np.array_equal(vps[:, [0, 2]] * [1, -1], np.concatenate([g.view_points for g in c.goals]))
        assert all(v.iou is None for g in h.goals for v in g.view_points)


def _pair(setup, index):
    """(habitat.Env, calnav env) both at calnav episode ``index``."""
    import gymnasium as gym

    import calnav.envs  # noqa: F401

    hcfg, env_cfg, calnav = setup
    henv = _habitat_env(hcfg)
    henv.episodes = [henv.episodes[index]]
    # calnav's env in metres (habitat-lab's config normalises depth; _compare maps it back)
    cenv = gym.make("calnav/ObjectNav-v0", split="val", config=replace(env_cfg, normalize_depth=False)).unwrapped
    return henv, cenv


def _compare(hobs, hm, cobs, cinfo, env_cfg):
    # bit for bit: calnav computes gps / compass with habitat-lab's own arithmetic (envs/task.py)
    assert np.array_equal(hobs["gps"], cobs["gps"]) and hobs["gps"].dtype == cobs["gps"].dtype
    assert np.array_equal(hobs["compass"], cobs["compass"]) and hobs["compass"].dtype == cobs["compass"].dtype
    assert hobs["objectgoal"][0] == cobs["objectgoal"][0]
    assert np.array_equal(hobs["rgb"], cobs["rgb"])
    # habitat-sim's depth: clipped to [min, max] and normalised; 0 (too near, nothing hit) and 1
    # (too far) are what calnav's metres mark invalid (0)
    x, d = hobs["depth"][..., 0], cobs["depth"][..., 0]
    valid = (x > 0) & (x < 1)
    assert np.array_equal(valid, d > 0)
    lo, hi = env_cfg.min_depth_m, env_cfg.max_depth_m
    assert np.allclose(lo + x[valid] * (hi - lo), d[valid], atol=TOL)
    for theirs, ours in (("distance_to_goal", "distance_to_goal"), ("success", "success"), ("spl", "spl"),
                         ("soft_spl", "softspl")):
        assert abs(hm[theirs] - cinfo[ours]) < TOL, (theirs, hm[theirs], cinfo[ours])


@pytest.mark.parametrize("source", ["script", "oracle"])
def test_stock_sensors_and_measures_equal_calnavs(setup, source):
    """Step for step: GPS / compass / goal / rgb and DistanceToGoal / Success / SPL / SoftSPL
    equal calnav's env (gps / compass exactly, the rest to 1e-5), on a scripted episode (looks, collisions, a STOP far from the
    goal) and on the oracle's actions (a STOP at the goal: Success 1, SPL > 0)."""
    from calnav.envs.oracle import OracleAgent

    hcfg, env_cfg, _ = setup
    henv, cenv = _pair(setup, 1)
    cobs, cinfo = cenv.reset(options={"episode_index": 1})
    hobs = henv.reset()
    _compare(hobs, henv.get_metrics(), cobs, cinfo, env_cfg)
    oracle = OracleAgent(cenv)
    oracle.reset(cobs)
    actions = iter(SCRIPT)
    done = False
    while not done:
        a = int(next(actions) if source == "script" else oracle.act(cobs))
        cobs, _, term, trunc, cinfo = cenv.step(a)
        hobs = henv.step(Action(a).name.lower())
        _compare(hobs, henv.get_metrics(), cobs, cinfo, env_cfg)
        done = term or trunc
        assert henv.episode_over == done
    assert henv.sim.previous_step_collided is False
    if source == "script":
        assert cenv.collisions > 0 and cinfo["success"] == 0.0
    else:
        assert cinfo["success"] == 1.0 and cinfo["spl"] > 0.5


def _run(cmd, out, *extra):
    return main([cmd, "--agent", "oracle", "--episodes", "0:3", "--output", str(out), "run.workers=1",
                 *CALNAV_SMALL, *extra])


def test_habitat_benchmark_agrees_with_objectnav(tmp_path, capsys):
    assert _run("habitat-benchmark", tmp_path / "hab", *HABITAT_SMALL) == 0
    assert "oracle (habitat-lab)" in capsys.readouterr().out
    assert _run("objectnav", tmp_path / "cal", f"env.resolution={W}x{H}") == 0
    hab, cal = read_records(tmp_path / "hab"), read_records(tmp_path / "cal")
    assert sorted(hab) == sorted(cal) == [0, 1, 2]
    assert_same_records(hab, cal, TOL)
    s = json.loads((tmp_path / "hab" / "summary.json").read_text())
    assert s["count"] == 3 and s["success"] == 1.0 and (tmp_path / "hab" / "habitat_config.yaml").exists()
    # resuming skips finished episodes; another habitat config in the same directory is refused
    assert _run("habitat-benchmark", tmp_path / "hab", *HABITAT_SMALL) == 0
    assert len((tmp_path / "hab" / "episodes.jsonl").read_text().splitlines()) == 3
    assert _run("habitat-benchmark", tmp_path / "hab", *HABITAT_SMALL, "habitat.simulator.turn_angle=15") == 2
    assert "different" in capsys.readouterr().err


def test_bad_input(tmp_path, capsys, setup):
    assert _run("habitat-benchmark", tmp_path / "a", "habitat.simulator.no_such_key=1") == 2
    err = capsys.readouterr().err
    assert "bad habitat config override" in err and "no_such_key" in err
    assert _run("habitat-benchmark", tmp_path / "b", "env.turn_angle_deg=15") == 2
    assert "env.turn_angle_deg is set by the habitat config" in capsys.readouterr().err
    # refused: forward_step_size=-1 (the agent would walk backwards), a NaN success distance (would hang)
    assert _run("habitat-benchmark", tmp_path / "c", "habitat.simulator.forward_step_size=-1") == 2
    assert "env.forward_step_m must be in [0.01, 2] metres, got -1.0" in capsys.readouterr().err
    for key in ("habitat.task.measurements.success.success_distance", "habitat.simulator.turn_angle"):
        assert _run("habitat-benchmark", tmp_path / "d", f"{key}=nan") == 2   # refused as calnav's keys are
        assert f"bad habitat config override {key}=nan: {key} expects a finite number" in capsys.readouterr().err
    assert not any((tmp_path / d).exists() for d in "abcd")

    from calnav.common.habitat_import import import_habitat

    hcfg, _, _ = setup
    cfg = hcfg.copy()
    with import_habitat().config.read_write(cfg):
        cfg.habitat.dataset.scenes_dir = str(tmp_path)  # scene ids become <tmp_path>/house_val_...
    env = _habitat_env(cfg)
    with pytest.raises(ValueError, match="is not a calnav scene"):
        env.reset()


def test_stand_ins_only_where_habitat_sim_is_missing():
    import sys

    from calnav.common.habitat_import import STUB_MARKER, STUBBED_MODULES, habitat_sim_available, import_habitat

    import_habitat()
    if habitat_sim_available():
        assert not any(getattr(sys.modules.get(m), STUB_MARKER, False) for m in STUBBED_MODULES)
        return
    assert all(getattr(sys.modules[m], STUB_MARKER, False) for m in STUBBED_MODULES)
    from habitat.core.batch_rendering.env_batch_renderer import EnvBatchRenderer

    with pytest.raises(ImportError, match="needs habitat-sim"):
        EnvBatchRenderer()


def test_habitat_benchmark_runs_the_configs_the_preflight_checked(tmp_path, monkeypatch):
    """As every other command (tests/eval/test_preflight.py): calnav's config and habitat-lab's
    are loaded once, checked, and handed to the command as they are."""
    from tests.eval.test_preflight import assert_runs_the_checked_configs

    checked = assert_runs_the_checked_configs(["habitat-benchmark", "--output", str(tmp_path / "hb")], monkeypatch)
    assert type(checked[0]).__name__ == "Config" and len(checked) == 2


def test_habitat_benchmark_gt_segmenter_without_semantic_sensor_is_one_line(tmp_path, capsys):
    """The default habitat config has no semantic sensor: the peanut agent with the gt
    segmenter used to die in habitat-lab's loop with a KeyError traceback."""
    out = tmp_path / "hb"
    assert main(["habitat-benchmark", "--agent", "peanut", "--episodes", "0:1", "--output", str(out),
                 "agent.segmenter=gt"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "reads the ground-truth semantic observation" in err[0] and not out.exists()
