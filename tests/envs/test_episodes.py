"""Episode generation: determinism, distances, view points, Habitat JSON schema, bad input."""
import gzip
import json
import math

import numpy as np
import open3d as o3d
import pytest

from tests.conftest import small_or_full
from calnav.envs.config import EnvConfig
from calnav.envs.episode_files import episodes_from_habitat, episodes_to_habitat, habitat_quaternion_to_yaw
from calnav.envs.episodes import generate_scene_episodes, goal_mask, load_split, parse_episode_range, split_dir
from calnav.envs.task import yaw_to_habitat_quaternion
from calnav.envs.navigation import NavGrid
from calnav.envs.primitives import box_room_scene
from calnav.envs.render import Camera, Renderer
from calnav.envs.scenes import load_scene
from calnav.eval.config import load_config


def _scene_tools(scene, cfg):
    r = Renderer(scene, Camera.from_config(cfg))
    return r.raycasting_scene, NavGrid.build(scene, cfg, r.raycasting_scene)


def test_generation_is_deterministic(small_env_config):
    cfg = small_env_config
    scene = load_scene("house_val_0000", cfg.dataset)
    rs, nav = _scene_tools(scene, cfg)
    a = generate_scene_episodes("house_val_0000", scene, nav, rs, cfg, 6, seed=5)
    b = generate_scene_episodes("house_val_0000", scene, nav, rs, cfg, 6, seed=5)
    c = generate_scene_episodes("house_val_0000", scene, nav, rs, cfg, 6, seed=6)
    assert episodes_to_habitat(a) == episodes_to_habitat(b)
    assert episodes_to_habitat(a) != episodes_to_habitat(c)


def test_split_distances_and_median():
    # The default val split (what README reports) in full; a smaller one in `make test`.
    cfg = load_config(None, [f"env.dataset.val_scenes={small_or_full(12, 30)}", "env.resolution=64x48"]).env
    eps = load_split("val", cfg, progress=False)
    d = np.array([e.geodesic_distance for e in eps])
    assert len(eps) == cfg.dataset.val_scenes * cfg.dataset.episodes_per_scene
    assert d.min() >= cfg.dataset.min_geodesic_m and d.max() <= cfg.dataset.max_geodesic_m
    assert np.median(d) >= 5.0
    assert {e.object_category for e in eps} == {"chair", "bed", "plant", "toilet", "tv_monitor", "sofa"}
    for e in eps[:40]:
        assert e.geodesic_distance >= e.euclidean_distance - 0.1  # a path is never shorter than a line


def test_view_points_are_navigable_near_and_see_the_object(small_env_config):
    cfg = small_env_config
    eps = load_split("val", cfg, progress=False)
    ep = eps[0]
    scene = load_scene(ep.scene_id, cfg.dataset)
    rs, nav = _scene_tools(scene, cfg)
    for goal in ep.goals:
        assert scene.instance_class(goal.object_id) == scene.class_names.index(ep.object_category)
        rc = nav.to_cell(goal.view_points)
        assert nav.navigable[rc[:, 0], rc[:, 1]].all()
        obj = scene.instance_triangles(goal.object_id).reshape(-1, 3)
        # horizontal distance from each view point to the object's vertices' hull, loosely
        nearest = np.min(np.linalg.norm(goal.view_points[:, None, :] - obj[None, :, :2], axis=2), axis=1)
        extent = np.linalg.norm(obj[:, :2].max(0) - obj[:, :2].min(0))
        assert (nearest <= cfg.view_point_radius_m + extent).all()
        # line of sight from a few view points to the object centroid region hits the object
        eye = np.column_stack([goal.view_points[:20], np.full(min(20, len(goal.view_points)), cfg.camera_height_m)])
        seen = 0
        for e in eye:
            dirs = obj - e
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
            rays = np.column_stack([np.repeat(e[None], len(dirs), 0), dirs]).astype(np.float32)
            prim = rs.cast_rays(o3d.core.Tensor(rays))["primitive_ids"].numpy().astype(np.int64)
            hit = prim[prim != o3d.t.geometry.RaycastingScene.INVALID_ID]
            seen += int((scene.tri_instance[hit] == goal.object_id).any())
        assert seen == len(eye)


def test_episode_start_distance_matches_geodesic(small_env_config):
    cfg = small_env_config
    ep = load_split("val", cfg, progress=False)[1]
    scene = load_scene(ep.scene_id, cfg.dataset)
    _, nav = _scene_tools(scene, cfg)
    field = nav.geodesic_field(goal_mask(nav, ep.goals))
    assert field.distance(ep.start_position) == pytest.approx(ep.geodesic_distance, abs=1e-6)
    assert nav.is_navigable(ep.start_position)


def test_habitat_schema_round_trip(small_env_config):
    cfg = small_env_config
    load_split("val", cfg, progress=False)
    path = split_dir("val", cfg) / "content" / "house_val_0000.json.gz"
    data = json.loads(gzip.open(path, "rt").read())
    e0 = data["episodes"][0]
    assert set(e0) >= {"episode_id", "scene_id", "start_position", "start_rotation", "object_category",
                       "info", "goals"}
    assert "geodesic_distance" in e0["info"]
    key = f"{e0['scene_id']}_{e0['object_category']}"
    goal = data["goals_by_category"][key][0]
    assert set(goal) >= {"object_id", "object_category", "position", "view_points"}
    assert e0["start_position"][1] == 0.0  # Habitat is y-up: height is the second coordinate
    back = episodes_from_habitat(data)
    assert episodes_to_habitat(back) == data


@pytest.mark.parametrize("yaw", [0.0, 0.3, math.pi / 2, 3.0, 5.9])
def test_yaw_quaternion_round_trip(yaw):
    q = yaw_to_habitat_quaternion(yaw)
    assert np.linalg.norm(q) == pytest.approx(1.0)
    assert habitat_quaternion_to_yaw(q) == pytest.approx(yaw, abs=1e-9)


def test_habitat_forward_convention():
    # calnav yaw = pi/2 faces +y (north); in Habitat (x, z, -y) that is -z_h, Habitat's default forward
    q = yaw_to_habitat_quaternion(math.pi / 2)
    assert q == pytest.approx([0.0, 0.0, 0.0, 1.0])


def test_bad_split_and_range(small_env_config):
    with pytest.raises(ValueError, match="valid splits: train, val, test"):
        load_split("validation", small_env_config)
    with pytest.raises(ValueError, match="outside the split, which has episodes 0:8"):
        parse_episode_range("5:20", 8)
    with pytest.raises(ValueError, match="use N or A:B"):
        parse_episode_range("five", 8)
    assert list(parse_episode_range("2:4", 8)) == [2, 3]


def test_scene_without_goal_instance_is_an_error():
    cfg = EnvConfig(resolution=(64, 48))
    scene = box_room_scene(objects=(("table", (0.5, -0.5), (1.0, 0.6, 0.75)),))
    rs, nav = _scene_tools(scene, cfg)
    with pytest.raises(ValueError, match="no reachable, visible instance of any goal category"):
        generate_scene_episodes("box", scene, nav, rs, cfg, 3, seed=0)


def _small_split(small_env_config):
    from calnav.envs.episodes import split_dir

    eps = load_split("val", small_env_config, progress=False)
    return eps, split_dir("val", small_env_config) / "content"


@pytest.mark.parametrize("damage", ["truncated", "wrong layout", "not gzip"])
def test_damaged_episode_cache_is_regenerated(small_env_config, damage):
    eps, content = _small_split(small_env_config)
    path = sorted(content.glob("*.json.gz"))[0]
    if damage == "truncated":       # a killed writer: gzip raises EOFError
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif damage == "wrong layout":  # valid JSON, not an episode file: KeyError
        with gzip.open(path, "wt") as f:
            json.dump({"episodes": [{"episode_id": "x"}]}, f)
    else:
        path.write_text("not gzip")
    again = load_split("val", small_env_config, progress=False)
    assert [e.episode_id for e in again] == [e.episode_id for e in eps]
    assert all(np.array_equal(a.start_position, b.start_position) for a, b in zip(again, eps))


def test_damaged_episode_file_is_named(tmp_path):
    from calnav.envs.episode_files import read_episode_file

    path = tmp_path / "given.json.gz"
    with gzip.open(path, "wt") as f:
        json.dump({"episodes": [{"episode_id": "x"}]}, f)
    with pytest.raises(ValueError, match=r"damaged episode file .*given.json.gz.*'scene_id'"):
        read_episode_file(path)
    path.write_bytes(b"\x1f\x8b\x08\x00")   # a gzip header, then nothing
    with pytest.raises(ValueError, match=r"episode file .*given.json.gz"):
        read_episode_file(path)


def test_old_episode_files_get_the_iou_key_and_nothing_else_changes(small_env_config):
    """habitat-lab's ObjectViewLocation needs ``iou`` on every view point: files cached before
    calnav wrote it get it on load, and the episodes read back the same."""
    from calnav.envs.episode_files import read_json_gz, write_json_gz

    cfg = small_env_config
    before = load_split("val", cfg, progress=False)
    path = split_dir("val", cfg) / "content" / "house_val_0000.json.gz"
    data = read_json_gz(path)
    vps = [v for gs in data["goals_by_category"].values() for g in gs for v in g["view_points"]]
    assert vps and all(v["iou"] is None for v in vps)
    for v in vps:
        del v["iou"]
    write_json_gz(path, data)
    after = load_split("val", cfg, progress=False)
    fixed = read_json_gz(path)
    assert all("iou" in v for gs in fixed["goals_by_category"].values() for g in gs for v in g["view_points"])
    for a, b in zip(before, after):
        assert a.episode_id == b.episode_id and a.start_yaw == b.start_yaw
        assert np.array_equal(a.start_position, b.start_position)


def test_view_points_parse_to_the_same_array_as_one_by_one():
    """The vectorised view-point parse gives exactly ``_from_habitat`` of each point and its
    height (and empty (0, 2), (0,) arrays for none)."""
    import numpy as np

    from calnav.envs.episode_files import _from_habitat, _view_points_from_habitat

    pts = [[1.25, 0.0, -3.5], [0.1, 0.2, 0.30000000000000004], [-7.0, 1.0, 2.0]]
    vps = [{"agent_state": {"position": p}} for p in pts]
    xy, heights = _view_points_from_habitat(vps)
    np.testing.assert_array_equal(xy, np.array([_from_habitat(p) for p in pts]))
    np.testing.assert_array_equal(heights, [0.0, 0.2, 1.0])   # Habitat's y: the points' heights
    assert _view_points_from_habitat([])[0].shape == (0, 2) and _view_points_from_habitat([])[1].shape == (0,)
    for bad in ([[1.0, 2.0, 3.0, 4.0]] * 3, [[1.0, 2.0]], [[1.0, 2.0, 3.0], [1.0]], [[]]):
        with pytest.raises(ValueError):
            _view_points_from_habitat([{"agent_state": {"position": q}} for q in bad])


def test_an_episode_file_is_parsed_once_per_process_until_it_changes(tmp_path, monkeypatch):
    """load_split's per-file cache: a second read of an unchanged file does not parse it again;
    a rewritten file (new stat) is parsed again and its new content returned."""
    import calnav.envs.episode_cache as episodes_mod
    from calnav.envs.episode_cache import cached_episodes
    from calnav.envs.episode_files import ObjectNavEpisode, episodes_to_habitat, write_json_gz

    ep = ObjectNavEpisode(episode_id="0", scene_id="s", start_position=np.zeros(2), start_rotation=[0.0, 0.0, 0.0, 1.0],
                          object_category="chair", geodesic_distance=2.0, euclidean_distance=1.5, goals=[])
    path = tmp_path / "s.json.gz"
    write_json_gz(path, episodes_to_habitat([ep]))
    calls = []
    real = episodes_mod.read_episode_file
    monkeypatch.setattr(episodes_mod, "read_episode_file", lambda p: calls.append(p) or real(p))
    first, second = cached_episodes(path), cached_episodes(path)
    assert len(calls) == 1 and [e.episode_id for e in second] == ["0"] and first is not second
    ep.episode_id = "7"
    write_json_gz(path, episodes_to_habitat([ep]))
    assert [e.episode_id for e in cached_episodes(path)] == ["7"] and len(calls) == 2
    path.unlink()
    assert cached_episodes(path) is None


def _episodes_equal(a, b) -> bool:
    """Two parsed episode lists hold the same values (dtypes and bytes included)."""
    def goal(g):
        return (g.object_id, type(g.object_id), g.object_category, g.position.dtype, g.position.tobytes(),
                g.view_points.dtype, g.view_points.shape, g.view_points.tobytes(), g.heights().tobytes())

    def episode(e):
        return (e.episode_id, e.scene_id, e.object_category, e.start_rotation, e.start_position.dtype,
                e.start_position.tobytes(), repr(e.geodesic_distance), repr(e.euclidean_distance),
                repr(e.start_height), [goal(g) for g in e.goals])

    return [episode(e) for e in a] == [episode(e) for e in b]


def test_the_parsed_sidecar_replaces_the_json_parse_until_anything_is_off(tmp_path, monkeypatch):
    """A content file's binary sidecar (episode_cache.read_sidecar): written on the first parse, read
    instead of the JSON by the next process (the same values, goal lists shared as parsed), and
    ignored -- the JSON parsed again -- when the JSON changes, the sidecar is damaged or of
    another format; a file outside a split's content folder gets none."""
    import calnav.envs.episode_cache as ef
    from calnav.envs import episode_cache as sc
    from calnav.envs.episode_files import GoalObject, ObjectNavEpisode, episodes_to_habitat, write_json_gz

    rng = np.random.default_rng(0)
    def goal(i, c, n):   # view points at heights other than 0: a second storey's
        return GoalObject(i, c, rng.normal(size=3), rng.normal(size=(n, 2)), rng.normal(size=n))

    goals = {c: [goal(i, c, int(rng.integers(0, 5))) for i in range(2)] for c in ("chair", "bed")}
    eps = [ObjectNavEpisode(episode_id=str(i), scene_id="s", start_position=rng.normal(size=2), start_height=0.25 * i,
                            start_rotation=[0.0, float(np.sin(i)), 0.0, float(np.cos(i))], object_category=c,
                            geodesic_distance=float(i) + 0.1, euclidean_distance=float("nan") if i == 2 else 1.5,
                            goals=goals[c]) for i, c in enumerate(["chair", "bed", "chair", "chair"])]
    path = tmp_path / "val" / "content" / "s.json.gz"
    write_json_gz(path, episodes_to_habitat(eps))
    calls = []
    real = ef.read_episode_file
    monkeypatch.setattr(ef, "read_episode_file", lambda p: calls.append(p) or real(p))
    parsed = ef.cached_episodes(path)
    assert len(calls) == 1 and sc.sidecar_path(path) == tmp_path / "val" / "parsed" / "s.npz"
    assert sc.sidecar_path(path).is_file()

    def fresh():   # another process: nothing parsed yet
        ef._PARSED.clear()
        return ef.cached_episodes(path)

    again = fresh()
    assert len(calls) == 1 and _episodes_equal(again, parsed) and _episodes_equal(again, real(path))
    assert again[0].goals is again[2].goals and again[0].goals is not again[1].goals
    sidecar = sc.sidecar_path(path)
    for damage in (lambda: sidecar.write_bytes(sidecar.read_bytes()[:200]),     # truncated
                   lambda: sidecar.write_bytes(b"not a zip file")):
        damage()
        assert _episodes_equal(fresh(), parsed)
    n = len(calls)
    with np.load(sidecar) as z:   # another format number: ignored
        arrays = {k: z[k] for k in z.files}
    arrays["format"][0] += 1
    np.savez(sidecar, **arrays)
    assert _episodes_equal(fresh(), parsed) and len(calls) == n + 1
    eps[0].episode_id = "changed"   # the JSON rewritten: its new content, not the sidecar's
    write_json_gz(path, episodes_to_habitat(eps))
    assert fresh()[0].episode_id == "changed" and fresh()[0].episode_id == "changed"
    loose = tmp_path / "loose.json.gz"   # not in a split's content folder: no sidecar
    write_json_gz(loose, episodes_to_habitat(eps))
    assert ef.cached_episodes(loose) is not None and sc.sidecar_path(loose) is None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["loose.json.gz", "val"]


def test_a_run_generates_only_the_scenes_its_range_needs_on_its_pool():
    # A fresh dataset key (an unusual distance range), 3 scenes of 2 episodes: the range 0:3 lies
    # in the first two scenes, so the third is never generated; the pool (2 workers) does it.
    from calnav.eval.episodes import episode_indices

    cfg = load_config(None, ["env.resolution=64x48", "env.dataset.val_scenes=3", "env.dataset.episodes_per_scene=2",
                             "env.dataset.min_geodesic_m=1.05", "run.workers=2"])
    content = split_dir("val", cfg.env) / "content"
    assert list(episode_indices("1:3", cfg.env, cfg.run, progress=False)) == [1, 2]
    assert sorted(p.name for p in content.glob("*.json.gz")) == ["house_val_0000.json.gz", "house_val_0001.json.gz"]
    prefix = load_split("val", cfg.env, progress=False, upto=3)
    assert len(prefix) == 4 and not (content / "house_val_0002.json.gz").exists()
    full = load_split("val", cfg.env, progress=False)   # generates the rest; the prefix is its start
    assert len(full) == 6 and episodes_to_habitat(full[:4]) == episodes_to_habitat(prefix)
    with pytest.raises(ValueError, match=r"outside the split, which has at most 6 episodes \(3 val scenes x "
                                         r"dataset.episodes_per_scene 2\)"):   # refused by the bound, at once
        episode_indices("0:7", cfg.env, cfg.run, progress=False)
    with pytest.raises(ValueError, match="empty or reversed"):
        episode_indices("5:2", cfg.env, cfg.run, progress=False)
