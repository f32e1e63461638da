"""Houses with storeys: the staircase geometry, the layered navigation grid (stairs up and down,
geodesics through them, snap / locate), episodes that cross storeys, the env on them, and that a
single-storey house, its grid, its episodes and every key are what they were before storeys."""
from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from calnav.envs.config import DatasetConfig, EnvConfig, plain_dict
from calnav.envs.episode_files import episodes_from_habitat, episodes_to_habitat
from calnav.envs.house import generate_house
from calnav.envs.navigation import NavGrid
from calnav.envs.oracle import LayeredFollower
from calnav.envs.stairs import StairSpec
from calnav.envs.task import Action

SEED = 2000003          # house_val_0003's seed: a three-room house whose stairs are in the living room
CFG = EnvConfig(resolution=(160, 120), dataset=DatasetConfig(storeys=2))


def _digest(*arrays) -> str:
    h = hashlib.sha1()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


@pytest.fixture(scope="module")
def house():
    scene = generate_house(SEED, storeys=2)
    return scene, NavGrid.build(scene, CFG)


# ------------------------------------------------------------------ one storey: unchanged
def test_single_storey_outputs_are_those_from_before_storeys():
    """Digests computed with the code before storeys existed (the same script on main): the
    mesh, its metadata, the navigation grid, generated episodes, the dataset key and a cache
    file name of a storeys=1 house must not move, or every cache and record would."""
    from calnav.envs.episodes import dataset_key, generate_scene_episodes
    from calnav.envs.render import Camera, Renderer
    from calnav.envs.scenes import scene_cache_path

    cfg = EnvConfig(resolution=(160, 120))
    s = generate_house(2000000)
    assert _digest(s.vertices, s.triangles, s.tri_class, s.tri_instance, s.tri_albedo, s.tri_texture) == "79e909772d44fdf8"
    assert hashlib.sha1(json.dumps(s.meta, sort_keys=True).encode()).hexdigest()[:16] == "b7e2d700aecf3e9d"
    g = NavGrid.build(s, cfg)
    assert not g.layered
    assert _digest(g.navigable, g.free, g.floor_heights, g.islands) == "7d2532a1d90a8d4e"
    eps = generate_scene_episodes("house_val_0000", s, g, Renderer(s, Camera.from_config(cfg)).raycasting_scene, cfg, 4, 7)
    text = json.dumps(episodes_to_habitat(eps), sort_keys=True)
    assert hashlib.sha1(text.encode()).hexdigest()[:16] == "30b73d95b2285fba"
    assert dataset_key(EnvConfig()) == "b21eb3fc32"
    assert scene_cache_path("house_val_0003").name == "house_val_0003_3627c44b3b20.npz"


def test_storeys_key_is_left_out_at_one_and_in_above():
    from calnav.eval.config import to_dict

    assert "storeys" not in plain_dict(DatasetConfig())
    assert plain_dict(DatasetConfig(storeys=2))["storeys"] == 2
    assert "storeys" not in to_dict(EnvConfig())["dataset"]
    from calnav.envs.episodes import dataset_key
    from calnav.envs.scenes import scene_cache_path

    assert dataset_key(CFG) != dataset_key(EnvConfig(resolution=(160, 120)))
    assert scene_cache_path("house_val_0003", CFG.dataset) != scene_cache_path("house_val_0003")


@pytest.mark.parametrize("kwargs, words", [({"storeys": 0}, "storeys"), ({"storeys": 4}, "storeys"),
                                           ({"storeys": 2, "style": "scanned"}, "scans"),
                                           ({"storeys": 2, "scene_dir": "/tmp"}, "user scenes")])
def test_bad_storeys_refused(kwargs, words):
    with pytest.raises(ValueError, match=words):
        DatasetConfig(**kwargs)


# ------------------------------------------------------------------------- stairs geometry
def test_staircase_geometry(house):
    scene, _ = house
    st = scene.meta["stairs"][0]
    spec, storey_h = StairSpec(), scene.meta["storey_height_m"]
    assert st["n_steps"] % 2 == 0 and storey_h / st["n_steps"] <= spec.max_rise_m < CFG.navmesh.agent_max_climb_m
    x0, y0, x1, y1 = st["rect"]
    tris = scene.vertices[scene.triangles].astype(np.float64)
    centre = tris.mean(axis=1)
    normal = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    up = normal[:, 2] > 1e-9 * np.linalg.norm(normal, axis=1).max()
    inside = (centre[:, 0] > x0 + 0.01) & (centre[:, 0] < x1 - 0.01) & (centre[:, 1] > y0 + 0.01) & (centre[:, 1] < y1 - 0.01)
    floor = scene.class_names.index("floor")
    tread_z = np.unique(np.round(centre[inside & up & (scene.tri_class == floor), 2], 4))
    rise = storey_h / st["n_steps"]
    # every tread height 1..n-1 rises (the last step is the upper floor), the landing at n/2 among them
    assert np.allclose(tread_z, rise * np.arange(1, st["n_steps"]), atol=1e-4)
    # the upper slab is open over the stairs: no floor facing up at the upper storey's height inside
    upper = np.isclose(centre[:, 2], storey_h, atol=1e-3) & up & (scene.tri_class == floor)
    assert upper.any() and not (upper & inside).any()
    # railings (class wall) stand on the upper floor along the opening
    wall = scene.class_names.index("wall")
    z_lo, z_hi = tris[..., 2].min(axis=1), tris[..., 2].max(axis=1)
    railing = (scene.tri_class == wall) & np.isclose(z_lo, storey_h, atol=1e-3) & \
        np.isclose(z_hi, storey_h + spec.railing_height_m, atol=1e-3)
    assert railing.sum() >= 8
    # both storeys are furnished with goal objects
    storeys = {o["storey"] for o in scene.meta["objects"] if o["class"] in ("bed", "toilet", "sofa", "chair", "plant")}
    assert storeys == {0, 1}


def test_storeys_three_stack_two_staircases():
    scene = generate_house(2000001, storeys=3)
    stairs = scene.meta["stairs"]
    assert [s["lower"] for s in stairs] == [0, 1] and len(scene.meta["storey_z"]) == 3
    grid = NavGrid.build(scene, CFG)
    assert grid.n_layers == 3 and grid.stats["islands"] >= 1
    assert (grid.islands[grid.navigable] == 0).mean() > 0.95   # one island joins the three storeys


# ------------------------------------------------------------------------- layered grid
def test_layered_grid_is_one_island_over_both_storeys(house):
    _, grid = house
    assert grid.layered and grid.n_layers == 2 and grid.navigable.shape[0] == 2
    for k in range(2):
        assert (grid.islands[k][grid.navigable[k]] == 0).mean() > 0.95


def _walk(grid, start_xy, start_layer, goal_mask):
    """Execute the layered follower's plan; the visited (xy, layer, floor height)."""
    field = grid.geodesic_field(goal_mask)
    actions = LayeredFollower(grid, CFG).plan(start_xy, start_layer, 0.0, field)
    assert actions is not None and actions[-1] == Action.STOP
    xy, layer, yaw, out = np.array(start_xy), start_layer, 0.0, []
    for a in actions[:-1]:
        if a == Action.MOVE_FORWARD:
            xy, layer, moved = grid.move_forward(xy, layer, yaw, CFG.forward_step_m)
            assert moved
        else:
            yaw = (yaw + (1 if a == Action.TURN_LEFT else -1) * np.radians(CFG.turn_angle_deg)) % (2 * np.pi)
        out.append((xy.copy(), layer, grid.floor_height(xy, layer)))
    return field, out


def _floor_cell(grid, layer, far_from=None):
    cells = np.argwhere(grid.navigable[layer] & (np.abs(grid.floor_heights[layer] - grid.storey_z[layer]) < 0.01))
    xy = grid.to_world(cells)
    if far_from is None:
        return xy[len(xy) // 2]
    return xy[np.argmax(np.linalg.norm(xy - far_from, axis=1))]


def test_walk_up_and_down_the_stairs(house):
    _, grid = house
    low = _floor_cell(grid, 0)
    high = _floor_cell(grid, 1, far_from=low)
    for (a, la), (b, lb) in (((low, 0), (high, 1)), ((high, 1), (low, 0))):
        goal = np.zeros(grid.navigable.shape, bool)
        goal[(lb, *grid.to_cell(b))] = True
        field, visited = _walk(grid, a, la, goal)
        layers = [v[1] for v in visited]
        assert layers[-1] == lb and field.distance(visited[-1][0], lb) < CFG.success_distance_m
        assert sorted(set(layers)) == [0, 1]
        z = np.array([v[2] for v in visited])
        # a 0.25 m step crosses at most one riser (treads are 0.3 m): never a jump of a storey
        assert np.abs(np.diff(z)).max() <= StairSpec().max_rise_m + 1e-6
        assert z.max() - z.min() == pytest.approx(grid.storey_z[1] - grid.storey_z[0], abs=0.01)


def test_no_layer_change_off_the_stairs(house):
    """Walking into a wall of the lower storey never lifts the agent onto the floor above."""
    _, grid = house
    rng = np.random.default_rng(0)
    xy, layers = grid.sample_navigable(rng, 300)
    for p, k in zip(xy, layers):
        for yaw in np.linspace(0, 2 * np.pi, 8, endpoint=False):
            q, k2, moved = grid.move_forward(p, int(k), yaw, CFG.forward_step_m)
            if moved and k2 != k:   # only on the stairs, between neighbouring treads
                assert abs(grid.floor_height(q, k2) - grid.floor_height(p, int(k))) < 0.5


def test_geodesic_goes_through_the_stairs(house):
    _, grid = house
    low = _floor_cell(grid, 0)
    goal = np.zeros(grid.navigable.shape, bool)
    goal[(0, *grid.to_cell(low))] = True
    field = grid.geodesic_field(goal)
    assert np.isfinite(field.values[1][grid.navigable[1]]).all()   # the whole upper storey reaches it
    above = low   # straight above the goal, a storey up: the way round by the stairs is longer than the drop
    k = grid.locate(above, grid.storey_z[1])
    if k == 1:
        assert field.distance(above, 1) > 2.0
    stair_cells = grid.navigable & (np.abs(grid.floor_heights - grid.storey_z[:, None, None]) > 0.3)
    assert stair_cells[0].any() and stair_cells[1].any()


def test_locate_snap_and_storey_at(house):
    _, grid = house
    low, high = _floor_cell(grid, 0), _floor_cell(grid, 1)
    assert grid.locate(low, grid.storey_z[0] + 0.1) == 0
    assert grid.locate(high, grid.storey_z[1] - 0.2) == 1
    assert grid.locate(high, grid.storey_z[1] + 1.0) is None
    xy, layer = grid.snap_point(np.array([*high, grid.storey_z[1] + 0.3]), 0.5)
    assert layer == 1 and np.allclose(xy, high)
    assert grid.snap_point(np.array([*high, grid.storey_z[1] + 2.0]), 0.5) is None
    assert grid.storey_at(0.0) == 0 and grid.storey_at(grid.storey_z[1]) == 1
    xy, layers = grid.sample_navigable(np.random.default_rng(1), 50)
    assert xy.shape == (50, 2) and set(layers.tolist()) <= {0, 1}
    assert all(grid.is_navigable(p, int(k)) for p, k in zip(xy, layers))


# ------------------------------------------------------------------------------ episodes
def test_episodes_cross_storeys_and_keep_heights(house):
    from calnav.envs.render import Camera, Renderer
    from calnav.envs.storey_episodes import generate_layered_episodes

    scene, grid = house
    report: dict = {}
    eps = generate_layered_episodes("house_val_0003", scene, grid, Renderer(scene, Camera.from_config(CFG)).raycasting_scene,
                                    CFG, 10, 3, report=report)
    assert len(eps) == 10 and report["cross_storey"] == sum(e.crosses_storeys for e in eps) >= 3
    for e in eps:
        assert e.start_height == pytest.approx(grid.storey_z[e.start_storey], abs=CFG.navmesh.agent_max_climb_m)
        assert grid.locate(e.start_position, e.start_height) == e.start_storey
    data = episodes_to_habitat(eps)
    start = data["episodes"][0]["start_position"]
    assert start[1] == pytest.approx(eps[0].start_height)   # Habitat's y is the height
    back = episodes_from_habitat(json.loads(json.dumps(data)))
    assert [(e.start_storey, e.goal_storey) for e in back] == [(e.start_storey, e.goal_storey) for e in eps]
    assert np.allclose(back[0].goals[0].heights(), eps[0].goals[0].heights())


def test_sidecar_keeps_storeys(tmp_path, house):
    from calnav.envs.episode_cache import _stat_key, read_sidecar, sidecar_path, write_sidecar
    from calnav.envs.episode_files import write_json_gz
    from calnav.envs.render import Camera, Renderer
    from calnav.envs.storey_episodes import generate_layered_episodes

    scene, grid = house
    eps = generate_layered_episodes("house_val_0003", scene, grid, Renderer(scene, Camera.from_config(CFG)).raycasting_scene,
                                    CFG, 4, 5)
    path = tmp_path / "val" / "content" / "house_val_0003.json.gz"
    path.parent.mkdir(parents=True)
    write_json_gz(path, episodes_to_habitat(eps))
    write_sidecar(path, _stat_key(path), eps)
    with np.load(sidecar_path(path)) as z:
        assert z["storeys"].shape == (4, 2)   # (a single-storey sidecar has none: both 0)
    back = read_sidecar(path, _stat_key(path))
    assert [(e.start_height, e.start_storey, e.goal_storey) for e in back] == \
        [(e.start_height, e.start_storey, e.goal_storey) for e in eps]


# ----------------------------------------------------------------------------------- env
def test_env_oracle_climbs_and_the_camera_follows_the_floor(house):
    from calnav.envs.objectnav_env import ObjectNavEnv
    from calnav.envs.oracle import OracleAgent
    from calnav.envs.render import Camera, Renderer
    from calnav.envs.storey_episodes import generate_layered_episodes

    scene, grid = house
    eps = generate_layered_episodes("house_val_0003", scene, grid, Renderer(scene, Camera.from_config(CFG)).raycasting_scene,
                                    CFG, 6, 11)
    ep = next(e for e in eps if e.crosses_storeys)
    env = ObjectNavEnv(config=CFG, episodes=[ep])
    obs, info = env.reset(options={"episode_index": 0})
    assert (info["start_storey"], info["goal_storey"], info["storey"]) == (ep.start_storey, ep.goal_storey, ep.start_storey)
    agent, storeys, done = OracleAgent(env), [], False
    agent.reset(obs)
    while not done:
        obs, _, terminated, truncated, info = env.step(agent.act(obs))
        done = terminated or truncated
        storeys.append(info["storey"])
        # the camera rides the floor under the agent, on the stairs too
        assert obs["camera_pose"][2, 3] == pytest.approx(env.navgrid.floor_height(env.position, env.layer)
                                                         + CFG.camera_height_m)
    assert info["success"] == 1.0 and storeys[-1] == ep.goal_storey
    # the path walked is no shorter than the geodesic through the stairs
    assert info["path_length"] >= ep.geodesic_distance
