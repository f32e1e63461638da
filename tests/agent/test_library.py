"""The agent as a library (``agent.navigator.Navigator``) on calnav's own env: an episode driven
through it takes calnav objectnav's actions (from gps / compass, and from the camera pose);
a pose becomes Habitat's gps / compass; the map is read and saved; bad inputs are one line;
docs/robot.md's example runs."""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from calnav.eval.config import agent_setup, load_config

REPO = Path(__file__).resolve().parents[2]
OVERRIDES = ["env.resolution=160x120", "env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=6",
             "env.max_episode_steps=200", "agent.map_size_m=24", "mapping.initial_alloc_mb=32",
             "agent.map_resolution=80x60"]


@pytest.fixture(scope="module")
def setup():
    import gymnasium as gym

    from calnav import envs

    cfg = load_config(None, OVERRIDES)
    env = gym.make(envs.ENV_ID, split="val", config=cfg.env)
    index = int(np.argmin([ep.geodesic_distance for ep in env.unwrapped.episodes]))   # explores, detects, stops
    return cfg, env, index


def _drive(env, index: int, navigators: dict, key: str):
    """Episode ``index`` stepped with the actions of ``navigators[key]``; every navigator acts on
    each observation, given the pose as it names ("gps": gps / compass, "pose": the 4x4 camera
    pose). Returns {name: decisions}, the observations with the env's true (x, y, yaw) under
    "xyyaw", and the env's last info."""
    ep = env.unwrapped.episodes[index]
    obs, info = env.reset(options={"episode_index": index})
    decisions = {name: [] for name in navigators}
    for nav in navigators.values():
        nav.reset(ep.object_category)
    observations, done = [], False
    while not done:
        for name, nav in navigators.items():
            pose = {"gps": obs["gps"], "compass": obs["compass"]} if name == "gps" else {"pose": obs["camera_pose"]}
            decisions[name].append(nav.act(obs["rgb"], obs["depth"], semantic=obs["semantic"], **pose))
        observations.append({**obs, "xyyaw": (*env.unwrapped.position, env.unwrapped.yaw)})
        obs, _, terminated, truncated, info = env.step(decisions[key][-1].action)
        done = terminated or truncated
    return decisions, observations, info


@pytest.fixture(scope="module")
def library_episode(setup):
    """The episode through two Navigators (gps / compass, the 4x4 camera pose), stepping with
    the first's actions."""
    from calnav.agent.navigator import Navigator

    cfg, env, index = setup
    navs = {"gps": Navigator(agent_setup(cfg)), "pose": Navigator(agent_setup(cfg))}
    decisions, observations, info = _drive(env, index, navs, "gps")
    return navs["gps"], decisions, observations, info


def test_an_episode_through_the_library_takes_calnav_objectnavs_actions(setup, library_episode):
    """calnav objectnav's episode (``eval.objectnav.run.run_one_episode``, the rollout loop, on the
    agent its workers build: a Navigator run as an ``EpisodeAgent``) and the same episode driven
    through the robot's entry point, ``Navigator.act``: the same actions step by step, hence the
    same record; the same with the pose given as the 4x4 camera pose instead of gps / compass."""

    from calnav.agent.navigator import EpisodeAgent, Navigator
    from calnav.eval.objectnav.run import _warm_env_agent, run_one_episode

    cfg, env, index = setup
    _, decisions, _, info = library_episode
    _, agent = _warm_env_agent(cfg, agent_setup(cfg, "peanut"))   # what a worker of calnav objectnav builds
    assert isinstance(agent, EpisodeAgent) and isinstance(agent.navigator, Navigator)
    actions, act = [], agent.act

    def recorded(obs):
        step = act(obs)
        actions.append(step.action)   # what objectnav's loop sends, step by step
        return step
    agent.act = recorded
    record = run_one_episode(env, agent, index)
    for name, got in decisions.items():
        assert [int(d.action) for d in got] == actions, name
    assert 0 in actions and {1, 2, 3} <= set(actions)   # it explored, turned and stopped
    assert {d.mode for d in decisions["gps"]} >= {"spin", "explore", "goal", "stop"}
    for key in ("success", "spl", "steps", "path_length", "collisions", "distance_to_goal"):
        assert info[key] == record[key], key
    assert record["stop_reason"] == "stop" and record["steps"] == len(actions)


def test_a_pose_becomes_habitat_gps_and_compass(setup, library_episode):
    """On every step of a real episode, the camera pose (4x4, and the env's (x, y, yaw))
    relative to the first step gives the env's own gps bit for bit and its compass (the same
    angle: at +-pi either sign)."""
    from calnav.agent.navigator import StartFrame, planar_pose

    _, _, observations, _ = library_episode
    turned = False
    for form in ("camera_pose", "xyyaw"):
        start = StartFrame(*planar_pose(observations[0][form]))
        for obs in observations:
            gps, compass = start.gps_compass(*planar_pose(obs[form]))
            np.testing.assert_array_equal(gps, obs["gps"], err_msg=form)
            assert gps.dtype == compass.dtype == np.float32 and compass.shape == (1,)
            d = (float(compass[0]) - float(obs["compass"][0]) + math.pi) % (2 * math.pi) - math.pi
            assert abs(d) < 1e-6, form
            turned |= abs(float(obs["compass"][0])) > 1.0
    # and back: the start frame's points in the world of the poses (a waypoint for a robot)
    for obs, decision in zip(observations, library_episode[1]["pose"]):
        np.testing.assert_allclose(start.world(decision.position), obs["xyyaw"][:2], atol=1e-5)
    assert turned and np.abs(observations[-1]["gps"]).max() > 1.0   # it moved and turned


def test_pose_conversion_frames_and_signs():
    """Habitat's conventions by hand: gps is (forward, right) of the start heading, compass is
    counter-clockwise; a 4x4 camera pose reads as its optical axis' heading."""
    from calnav.agent.navigator import LEVEL_TOLERANCE_DEG, StartFrame, planar_pose
    from calnav.envs.task import camera_pose

    start = StartFrame(np.array([1.0, 2.0]), math.pi / 2)            # at (1, 2) facing +y
    for xy, yaw, gps, compass in [((1.0, 3.0), math.pi / 2, (1.0, 0.0), 0.0),      # 1 m ahead
                                  ((0.0, 2.0), math.pi / 2, (0.0, -1.0), 0.0),     # 1 m to the left
                                  ((2.0, 2.0), math.pi, (0.0, 1.0), math.pi / 2)]:  # 1 m right, turned left
        g, c = start.gps_compass(np.array(xy), yaw)
        np.testing.assert_allclose(g, gps, atol=1e-6)
        np.testing.assert_allclose(c, [compass], atol=1e-6)
    xy, yaw = planar_pose(camera_pose((3.0, -1.0), 2.5, 0.88))
    np.testing.assert_allclose(xy, (3.0, -1.0))
    assert yaw == pytest.approx(2.5)
    assert planar_pose((1.0, 2.0, 0.3))[1] == 0.3
    tilt = math.radians(LEVEL_TOLERANCE_DEG + 1)
    with pytest.raises(ValueError, match=r"^the camera is pitched 3\.0 and rolled 0\.0 degrees from level"):
        planar_pose(camera_pose((0, 0), 0.0, 0.88, pitch=tilt))
    planar_pose(camera_pose((0, 0), 0.0, 0.88, pitch=math.radians(LEVEL_TOLERANCE_DEG - 1)))
    with pytest.raises(ValueError, match=r"pose must be a \(4, 4\) world-from-camera transform or \(x, y, yaw\); "
                                         r"got shape \(2,\)"):
        planar_pose((1.0, 2.0))


def test_the_decision_in_metres(library_episode):
    """Long- and short-term goals, the detected goal and the agent's position are metric points
    of the episode-start frame: the map's cells under them agree (visited where the agent stood,
    goal confidence at the goal's centre) and the short-term goal lies ring_cells away."""
    nav, decisions, _, _ = library_episode
    m = nav.map()
    last = decisions["gps"][-1]
    assert last.mode == "stop" and last.goal is not None and last.goal.accepted
    assert m.layer("visited")[m.cell(*last.position)]
    assert m.confidence(m.goal)[m.cell(*last.goal.centre)] >= nav.setup.agent.goal_threshold
    stg = [d for d in decisions["gps"] if d.short_term_goal is not None and d.mode == "explore"]
    assert stg and all(d.long_term_goal is not None for d in stg)
    ring = nav.setup.agent.ring_cells * nav.setup.agent.cell_m
    far = [math.dist(d.position, d.short_term_goal) for d in stg if math.dist(d.position, d.long_term_goal) > 2 * ring]
    assert far and max(abs(f - ring) for f in far) < 2 * nav.setup.agent.cell_m   # one cell from the ring, at most


def test_the_map_is_read_and_saved(library_episode, tmp_path):
    """map() is a copy of the explored window (origin in metres, cells along +x / +y) with the
    voxel map; save_map writes a calnav map file (calnav view opens it) that loads back equal."""
    from calnav.agent.navigator_map import MAP_FORMAT_VERSION, AgentMap
    from calnav.common.npz import load_versioned_npz
    from calnav.eval.sequence.map_cmd import MAP_FORMAT_VERSION as CALNAV_MAP_FORMAT

    nav, _, _, _ = library_episode
    m = nav.map()
    state = nav.agent.state
    assert m.semantic.shape == (len(nav.class_names), *m.channels.shape[1:]) and m.channels.dtype == bool
    assert m.layer("explored").sum() == state.channels[1].sum()   # the window holds every explored cell
    assert m.layer("explored").mean() > 0.3
    assert len(m.voxel_centres) > 1000 and m.voxel_probs.shape == (len(m.voxel_centres), len(m.class_names))
    lo, hi = m.origin, m.origin + np.array(m.channels.shape[:0:-1]) * m.cell_m
    assert ((m.voxel_centres[:, :2] >= lo - 0.5) & (m.voxel_centres[:, :2] <= hi + 0.5)).all()
    m.semantic[:] = 0                                              # a copy: the agent's map is untouched
    assert state.semantic.max() > 0
    path = nav.save_map(tmp_path / "map.npz")
    back = AgentMap.load(path)
    for field in ("origin", "channels", "semantic", "voxel_centres", "voxel_probs"):
        np.testing.assert_array_equal(getattr(back, field), getattr(nav.map(), field), err_msg=field)
    assert (back.class_names, back.goal, back.cell_m) == (m.class_names, m.goal, m.cell_m)
    assert MAP_FORMAT_VERSION == CALNAV_MAP_FORMAT
    arrays, meta = load_versioned_npz(path, CALNAV_MAP_FORMAT)
    assert arrays["centres"].shape[1] == 3 and meta["class_names"] == list(m.class_names)
    pytest.importorskip("rerun")
    from calnav.common.rerun_io import check_recording
    from calnav.eval.sequence.view import npz_recording

    check_recording(npz_recording(path))


def test_bad_inputs_are_one_line(setup):
    from calnav.agent.navigator import Navigator

    cfg, env, _ = setup
    nav = Navigator(agent_setup(cfg))
    obs, _ = env.reset(options={"episode_index": 0})
    rgb, depth = obs["rgb"], obs["depth"]
    with pytest.raises(ValueError, match=r"^call reset\(goal\) before act\(\)$"):
        nav.act(rgb, depth, gps=obs["gps"], compass=obs["compass"])
    with pytest.raises(ValueError, match=r"^unknown goal 'chiar'; valid: chair \(0\), bed \(1\), plant \(2\), "):
        nav.reset("chiar")
    with pytest.raises(ValueError, match=r"^unknown goal 9; valid: "):
        nav.reset(9)
    assert nav.goal_id("bed") == 1 and nav.goal_id(np.int64(2)) == 2
    with pytest.raises(ValueError, match=r"^the agent has no map yet"):
        nav.map()
    assert nav.goal is None and nav.needs_semantic   # (gt: the simulator's semantic sensor)
    nav.reset("chair")
    assert nav.goal == "chair"
    for kwargs, message in [({}, r"^act\(\) needs the agent's pose"),
                            ({"gps": obs["gps"], "compass": obs["compass"], "pose": obs["camera_pose"]},
                             "^give either pose or gps and compass, not both$"),
                            ({"gps": [np.nan, 0.0], "compass": 0.0}, "^gps must be 2 finite numbers")]:
        with pytest.raises(ValueError, match=message):
            nav.act(rgb, depth, semantic=obs["semantic"], **kwargs)
    with pytest.raises(ValueError, match=r"^depth must be \(H, W\) or \(H, W, 1\) at the rgb's size 160x120; got shape "
                                         r"\(60, 80\)$"):
        nav.act(rgb, depth[::2, ::2, 0], pose=obs["camera_pose"])
    with pytest.raises(ValueError, match=r"^rgb must be \(H, W, 3\) uint8; got float32"):
        nav.act(rgb.astype(np.float32), depth, pose=obs["camera_pose"])
    with pytest.raises(ValueError, match=r"env.resolution=160x120"):   # the agent's own check: its sensor model
        nav.act(rgb[::2, ::2], depth[::2, ::2], pose=obs["camera_pose"], semantic=obs["semantic"][::2, ::2])
    oracle = load_config(None, [*OVERRIDES, "run.agent=oracle"])
    with pytest.raises(ValueError, match="needs the simulator's privileged handle"):
        Navigator(agent_setup(oracle))


def test_unit_and_frame_mix_ups_are_refused(setup):
    """What a robot's driver gets wrong that the agent would otherwise map into a blind search
    with no other sign: depth in raw millimetres (uint16 or float), normalised depth past 1 or
    metric depth with env.normalize_depth, yaw or compass in degrees, a non-rigid 4x4, a UTM
    map frame, poses in millimetres (one step of 250 'metres')."""
    import dataclasses

    from calnav.agent.navigator import Navigator, planar_pose

    cfg, env, _ = setup
    obs, _ = env.reset(options={"episode_index": 0})
    rgb, depth, sem, pose = obs["rgb"], obs["depth"], obs["semantic"], obs["camera_pose"]
    nav = Navigator(agent_setup(cfg))
    nav.reset("chair")
    for bad, message in [((depth * 1000).astype(np.uint16), r"^depth must be float metres \(env.normalize_depth is "
                                                            r"false\); got uint16: raw sensor units\?"),
                         (depth * 1000, r"valid pixels lie beyond 100 m: millimetres\? divide by 1000$")]:
        with pytest.raises(ValueError, match=message):
            nav.act(rgb, bad, pose=pose, semantic=sem)
    normalised = Navigator(agent_setup(dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, normalize_depth=True))))
    normalised.reset("chair")
    with pytest.raises(ValueError, match=r"^depth must be normalised \[0, 1\] .*pixels exceed 1 .*metric depth\? set "
                                         r"env.normalize_depth=false$"):
        normalised.act(rgb, depth, pose=pose, semantic=sem)
    with pytest.raises(ValueError, match=r"^compass 170 is not Habitat's EpisodicCompass, radians in \[-pi, pi\]"):
        nav.act(rgb, depth, gps=obs["gps"], compass=[170.0], semantic=sem)
    with pytest.raises(ValueError, match=r"^yaw 400 is not an angle in radians"):
        planar_pose((1.0, 2.0, 400.0))
    sheared = pose.copy()
    sheared[:3, :3] *= 2.0
    with pytest.raises(ValueError, match=r"^pose is not a rigid transform"):
        planar_pose(sheared)
    far = pose.copy()
    far[:2, 3] += (5e5, 4e6)
    with pytest.raises(ValueError, match=r"m from the world origin \(at most 8192\).*give poses in a local frame"):
        planar_pose(far)
    # inf (ROS REP 117: out of range) and NaN are invalid pixels, skipped by the map, not units
    from calnav.agent.navigator import check_depth

    holes = depth.copy()
    holes[: int(0.6 * len(holes))] = np.inf
    holes[-1] = np.nan
    check_depth(holes, normalised=False)
    check_depth(np.clip(holes / 5.0, 0, None), normalised=True)
    nav.act(rgb, depth, pose=pose, semantic=sem)   # a good first step, then a forward step read in millimetres
    moved = pose.copy()
    moved[:3, 3] += 250.0 * pose[:3, 2]
    with pytest.raises(ValueError, match=r"^the camera moved .* m between steps 1 and 2 .*poses in millimetres\?"):
        nav.act(rgb, depth, pose=moved, semantic=sem)


def test_a_refused_call_changes_nothing(setup):
    """A first act refused for its depth (uint16), given another pose: the good call after it
    gives what the good call alone gives -- its pose is the start frame, not the refused one's --
    and so for observe and begin (the episode loop's calls)."""
    from calnav.agent.navigator import EpisodeAgent, Navigator

    cfg, env, _ = setup
    obs, _ = env.reset(options={"episode_index": 0})
    rgb, depth, sem, pose = obs["rgb"], obs["depth"], obs["semantic"], obs["camera_pose"]
    elsewhere = pose.copy()
    elsewhere[:3, 3] += (3.0, -2.0, 0.0)
    elsewhere[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)   # level, facing +x
    alone, refused = Navigator(agent_setup(cfg)), Navigator(agent_setup(cfg))
    alone.reset("chair")
    refused.reset("chair")
    with pytest.raises(ValueError, match=r"^depth must be float metres .*got uint16"):
        refused.act(rgb, (depth * 1000).astype(np.uint16), pose=elsewhere, semantic=sem)
    assert refused.start_frame is None
    with pytest.raises(KeyError, match=r"observation lacks semantic, which the 'gt' segmenter needs"):
        refused.act(rgb, depth, pose=elsewhere)   # the segmenter's input, checked before the start frame too
    assert refused.start_frame is None
    want, got = alone.act(rgb, depth, pose=pose, semantic=sem), refused.act(rgb, depth, pose=pose, semantic=sem)
    assert got == want and got.position == pytest.approx((0.0, 0.0), abs=1e-6) and got.step == 1
    np.testing.assert_array_equal(refused.start_frame.xy, alone.start_frame.xy)
    assert refused.start_frame.yaw == alone.start_frame.yaw
    # the episode loop's calls: a refused begin, then the good one, is the good one alone
    loop, bad = EpisodeAgent(Navigator(agent_setup(cfg))), {**obs, "compass": np.array([170.0], np.float32)}
    with pytest.raises(ValueError, match=r"^compass 170 is not Habitat's EpisodicCompass"):
        loop.reset(bad)
    loop.reset(obs)
    fresh = EpisodeAgent(Navigator(agent_setup(cfg)))
    fresh.reset(obs)
    assert loop.act(obs).action == fresh.act(obs).action
    assert loop.navigator.observe(obs) == fresh.navigator.observe(obs)


def test_observe_checks_what_act_checks(setup):
    """observe on a Habitat observation refuses what act refuses, before anything changes: a
    compass in degrees, a gps that jumps 1 km between steps (millimetres), uint16 depth, a gps
    that is not 2 finite numbers."""
    from calnav.agent.navigator import Navigator

    cfg, env, _ = setup
    obs, _ = env.reset(options={"episode_index": 0})
    nav = Navigator(agent_setup(cfg))
    nav.reset()
    for change, message in [({"compass": np.array([170.0], np.float32)}, r"^compass 170 is not Habitat's EpisodicCompass"),
                            ({"gps": np.array([np.nan, 0.0], np.float32)}, r"^gps must be 2 finite numbers"),
                            ({"gps": np.zeros(3, np.float32)}, r"^gps must be 2 finite numbers"),
                            ({"depth": (obs["depth"] * 1000).astype(np.uint16)}, r"^depth must be float metres")]:
        with pytest.raises(ValueError, match=message):
            nav.observe({**obs, **change})
    assert nav.goal is None   # nothing began: the goal is still the first observation's to give
    first = nav.observe(obs)
    assert first.step == 1 and nav.goal == env.unwrapped.episode.object_category
    jump = {**obs, "gps": (obs["gps"] + np.array([1000.0, 0.0])).astype(np.float32)}
    with pytest.raises(ValueError, match=r"^the camera moved 1000 m between steps 1 and 2 .*poses in millimetres\?"):
        nav.observe(jump)
    assert nav.observe(obs).step == 2   # the refused step was not counted


def _docs_block(page: str, marker: str) -> str:
    """The first ```python block after ``marker`` in docs/<page>."""
    text = (REPO / "docs" / page).read_text()
    found = re.search(re.escape(marker) + r".*?```python\n(.*?)```", text, re.S)
    assert found, f"no python block after {marker!r} in docs/{page}"
    return found.group(1)


def test_the_docs_example_runs(tmp_path, monkeypatch, capsys):
    """docs/robot.md's library example, run as it is (from another directory)."""
    code = _docs_block("robot.md", "<!-- example: library -->")
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "docs/robot.md", "exec"), {"__name__": "__main__"})
    printed = capsys.readouterr().out
    assert re.search(r"^(STOP|MOVE_FORWARD|TURN_LEFT|TURN_RIGHT) .* success [01]\.0", printed, re.M), printed
    assert (tmp_path / "map.npz").is_file()


def test_the_ros_node_sketch_uses_only_the_library():
    """docs/robot.md's ROS 2 node (not run here: no ROS) parses and reaches calnav only through
    the library entry point (the Navigator, its setup, the action ids): never calnav.eval."""
    import ast

    code = _docs_block("robot.md", "## A ROS 2 node (a sketch)")
    calnav = {node.module for node in ast.walk(ast.parse(code))
              if isinstance(node, ast.ImportFrom) and node.module.split(".")[0] == "calnav"}
    assert calnav == {"calnav.agent.config", "calnav.agent.navigator", "calnav.agent.setup", "calnav.envs.task"}
    assert "self.nav.act(" in code and "import rclpy" in code
    assert not re.search(r"self\.nav\.(agent\b|_)", code)   # the Navigator's public surface only
