"""Scene library: ids, split seeds, procedural cache, user scene directories, errors."""
from __future__ import annotations

import json

import numpy as np
import pytest

from calnav.envs import scenes
from calnav.envs.config import DatasetConfig
from calnav.envs.house import HouseSpec
from calnav.envs.primitives import box_room_scene
from calnav.envs.scenes import (SPLITS, load_scene, parse_scene_id, procedural_scene_id, scene_cache_path, scene_seed,
                         split_scene_ids)
from calnav.envs.semantics import CLASS_ID

ARRAYS = ("vertices", "triangles", "tri_class", "tri_instance", "tri_albedo", "tri_texture")
LABEL_MAP = {"1": "floor", "5": "chair"}


def _write_scan(path, up_axis: str = "z") -> None:
    """A labelled PLY: a 4 x 4 m floor (raw label 1) and a 0.5 m box chair (raw label 5)."""
    from plyfile import PlyData, PlyElement

    from calnav.envs.primitives import box_mesh

    bv, bt = box_mesh((0.5, 0.5, 0.25), (0.5, 0.5, 0.5))
    v = np.vstack([[[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]], bv])
    t = np.vstack([[[0, 1, 2], [0, 2, 3]], bt + 4])
    if up_axis == "y":
        v = np.stack([v[:, 0], v[:, 2], -v[:, 1]], axis=1)
    vert = np.empty(len(v), [("x", "f4"), ("y", "f4"), ("z", "f4"), ("label", "i4")])
    vert["x"], vert["y"], vert["z"] = v.T
    vert["label"] = [1] * 4 + [5] * 8
    face = np.empty(len(t), [("vertex_indices", "O")])
    face["vertex_indices"] = [np.asarray(f, np.int32) for f in t]
    PlyData([PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")]).write(str(path))


@pytest.fixture(autouse=True)
def isolated_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("CALNAV_CACHE", str(tmp_path / "cache"))
    scenes.clear_scene_lru()
    yield tmp_path / "cache"
    scenes.clear_scene_lru()


def test_ids_round_trip_and_split_lists():
    assert procedural_scene_id("val", 3) == "house_val_0003"
    assert parse_scene_id("house_test_0042") == ("test", 42)
    cfg = DatasetConfig(train_scenes=5, val_scenes=3, test_scenes=2, calib_scenes=4)
    assert split_scene_ids("train", cfg) == [f"house_train_{i:04d}" for i in range(5)]
    assert [len(split_scene_ids(s, cfg)) for s in SPLITS] == [5, 3, 2, 4]
    assert len(split_scene_ids("val")) == DatasetConfig().val_scenes


def test_seeds_are_disjoint_across_splits_and_base_seeds():
    n = 2000
    seen: dict[int, tuple] = {}
    for base in (0, 1, 7):
        for split in SPLITS:
            for i in range(n):
                seed = scene_seed(procedural_scene_id(split, i), base)
                assert seed not in seen, f"{(base, split, i)} collides with {seen[seed]}"
                seen[seed] = (base, split, i)
    assert scene_seed("house_train_0000") == 1_000_000 and scene_seed("house_val_0005", 1) == 4_000_000 + 2_000_005
    assert scene_seed("house_calib_0003") == 3


@pytest.mark.parametrize("bad", ["house_dev_0001", "house_val_x", "val_0001", "", "house_val_0003.npz"])
def test_bad_ids_name_the_format(bad):
    with pytest.raises(ValueError, match="house_<split>_<NNNN>"):
        load_scene(bad)


def test_bad_split_and_out_of_range_index():
    with pytest.raises(ValueError, match="valid splits: train, val, test"):
        split_scene_ids("dev", DatasetConfig())
    with pytest.raises(ValueError, match="house_val_0000 .. house_val_0002"):
        load_scene("house_val_0003", DatasetConfig(val_scenes=3))
    with pytest.raises(ValueError, match="base seed"):
        scene_seed("house_val_0000", -1)


def test_procedural_cache_round_trip(isolated_cache):
    cfg = DatasetConfig(val_scenes=2)
    a = load_scene("house_val_0001", cfg)
    path = scene_cache_path("house_val_0001", cfg)
    assert path.exists() and path.parent == isolated_cache / "scenes" and a.name == "house_val_0001"
    assert load_scene("house_val_0001", cfg) is a                 # in-process LRU
    scenes.clear_scene_lru()
    b = load_scene("house_val_0001", cfg)                           # from disk
    assert b is not a
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.rooms == b.rooms and b.meta["seed"] == scene_seed("house_val_0001", cfg.seed)
    # a different spec or base seed is a different cache file
    assert scene_cache_path("house_val_0001", cfg, HouseSpec(walk_gap_m=0.7)) != path
    assert scene_cache_path("house_val_0001", DatasetConfig(val_scenes=2, seed=1)) != path
    c = load_scene("house_val_0001", DatasetConfig(val_scenes=2, seed=1))
    assert c.vertices.shape != a.vertices.shape or not np.array_equal(c.vertices, a.vertices)


def test_corrupt_cache_entry_is_regenerated(isolated_cache):
    cfg = DatasetConfig(train_scenes=1)
    a = load_scene("house_train_0000", cfg)
    path = scene_cache_path("house_train_0000", cfg)
    path.write_bytes(b"not a zip")
    scenes.clear_scene_lru()
    b = load_scene("house_train_0000", cfg)
    np.testing.assert_array_equal(a.vertices, b.vertices)


def test_lru_is_bounded():
    cfg = DatasetConfig(train_scenes=scenes.LRU_SIZE + 2)
    first = load_scene("house_train_0000", cfg)
    for i in range(1, scenes.LRU_SIZE + 2):
        load_scene(procedural_scene_id("train", i), cfg)
    assert len(scenes._lru) == scenes.LRU_SIZE
    assert load_scene("house_train_0000", cfg) is not first          # evicted, re-read from disk


def test_user_scene_dir_flat(tmp_path):
    d = tmp_path / "scans"
    d.mkdir()
    box_room_scene(name="boxy").save(d / "boxy.npz")
    _write_scan(d / "scan_a.ply")
    (d / "labels.json").write_text(json.dumps(LABEL_MAP))
    _write_scan(d / "scan_b.ply", up_axis="y")
    (d / "scan_b.labels.json").write_text(json.dumps({"label_map": LABEL_MAP, "up_axis": "y"}))
    cfg = DatasetConfig(scene_dir=str(d))
    for split in SPLITS:
        assert split_scene_ids(split, cfg) == ["boxy", "scan_a", "scan_b"]
    assert load_scene("boxy", cfg).name == "boxy"
    a, b = load_scene("scan_a", cfg), load_scene("scan_b", cfg)
    assert CLASS_ID["chair"] in a.classes_present()
    np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-5)
    with pytest.raises(ValueError, match="valid ids: boxy, scan_a, scan_b"):
        load_scene("house_val_0000", cfg)


def test_user_scene_dir_with_split_folders(tmp_path):
    for split, names in (("train", ["t1", "t2"]), ("val", ["v1"])):
        (tmp_path / split).mkdir()
        for n in names:
            box_room_scene(name=n).save(tmp_path / split / f"{n}.npz")
    cfg = DatasetConfig(scene_dir=str(tmp_path))
    assert split_scene_ids("train", cfg) == ["t1", "t2"] and split_scene_ids("val", cfg) == ["v1"]
    with pytest.raises(ValueError, match="no 'test' folder"):
        split_scene_ids("test", cfg)
    assert load_scene("v1", cfg).name == "v1"
    with pytest.raises(ValueError, match="not a directory"):
        split_scene_ids("val", DatasetConfig(scene_dir=str(tmp_path / "nowhere")))


def test_scan_with_any_file_name_gets_episodes(tmp_path):
    """README: put *.ply / *.npz scenes in a folder and set env.dataset.scene_dir; a scan called
    room.ply (not named like a procedural house) must work end to end."""
    from calnav.envs.episodes import load_split
    from calnav.eval.config import load_config

    d = tmp_path / "scans"
    d.mkdir()
    _write_scan(d / "room.ply")
    (d / "labels.json").write_text(json.dumps(LABEL_MAP))
    env = load_config(None, ["env.resolution=64x48", f"env.dataset.scene_dir={d}",
                             "env.dataset.episodes_per_scene=2", "env.dataset.min_geodesic_m=0.3"]).env
    eps = load_split("val", env, progress=False)
    assert len(eps) == 2 and {e.scene_id for e in eps} == {"room"} and eps[0].object_category == "chair"
    assert [e.episode_id for e in load_split("val", env, progress=False)] == [e.episode_id for e in eps]


def test_empty_scene_dir_says_no_scenes_found(tmp_path):
    with pytest.raises(ValueError, match=f"no scenes found in {tmp_path}"):
        split_scene_ids("val", DatasetConfig(scene_dir=str(tmp_path)))
    (tmp_path / "val").mkdir()
    with pytest.raises(ValueError, match=f"no scenes found in {tmp_path / 'val'}"):
        split_scene_ids("val", DatasetConfig(scene_dir=str(tmp_path)))


# --------------------------------------------------------- a cache file of another scene
def test_a_house_cache_copied_over_another_is_rebuilt(isolated_cache):
    """house_val_0001's cache file copied over house_val_0000's: the file names its house, seed
    and spec, so loading house_val_0000 rebuilds it (warning naming the file) instead of
    handing out the other house; the rewritten file is house_val_0000's again."""
    import shutil

    cfg = DatasetConfig(val_scenes=2)
    own, other = load_scene("house_val_0000", cfg), load_scene("house_val_0001", cfg)
    path = scene_cache_path("house_val_0000", cfg)
    shutil.copy(scene_cache_path("house_val_0001", cfg), path)
    scenes.clear_scene_lru()
    with pytest.warns(UserWarning, match=rf"scene cache {path} holds another scene \(scene_id 'house_val_0001', "
                                         r"expected 'house_val_0000'\); rebuilding it"):
        again = load_scene("house_val_0000", cfg)
    np.testing.assert_array_equal(again.vertices, own.vertices)
    assert not np.array_equal(again.vertices, other.vertices) or again.vertices.shape != other.vertices.shape
    from calnav.envs.scene import Scene
    assert Scene.load(path).meta["scene_id"] == "house_val_0000"


def test_a_scan_cache_of_another_house_or_settings_is_rebuilt(isolated_cache, monkeypatch):
    """The scan cache carries the house, its seed and the scan settings: another house's scan or
    a scan made with other settings copied over it is rescanned, never used. (The scanner is
    replaced by a fast stand-in that stamps the metadata scan_house stamps.)"""
    import shutil

    from calnav.envs.scanning import scanner
    from calnav.envs.scanning.config import SCANNER_VERSION, ScanningConfig
    from calnav.envs.scenes import scanned_cache_path
    from calnav.envs.trajectories import TRAJECTORY_VERSION

    scanned = []

    def fake_scan(scene, cfg, seed):
        scanned.append(scene.name)
        meta = {**scene.meta, "scan_seed": int(seed), "scanner_version": SCANNER_VERSION,
                "trajectory_version": TRAJECTORY_VERSION, "scanning": cfg.digest_items(), "style": "scanned"}
        return type(scene)(**{**scene.__dict__, "meta": meta})

    monkeypatch.setattr(scanner, "scan_house", fake_scan)
    cfg = DatasetConfig(val_scenes=2, style="scanned")
    noisier = DatasetConfig(val_scenes=2, style="scanned", scanning=ScanningConfig(axial_noise_m=0.01))
    load_scene("house_val_0000", cfg), load_scene("house_val_0001", cfg), load_scene("house_val_0000", noisier)
    assert scanned == ["house_val_0000", "house_val_0001", "house_val_0000"]
    path = scanned_cache_path("house_val_0000", cfg)
    for foreign, field in ((scanned_cache_path("house_val_0001", cfg), "scene_id"),
                           (scanned_cache_path("house_val_0000", noisier), "scanning")):
        shutil.copy(foreign, path)
        scenes.clear_scene_lru()
        with pytest.warns(UserWarning, match=rf"scene cache {path} holds another scene \({field} "):
            assert load_scene("house_val_0000", cfg).meta["scanning"]["axial_noise_m"] == \
                ScanningConfig().axial_noise_m
        assert scanned[-1] == "house_val_0000"
    scenes.clear_scene_lru()
    load_scene("house_val_0000", cfg)   # the rebuilt file is its own: no rescan
    assert len(scanned) == 5
    # a scan walked before every CPU walked alike (no trajectory_version) is scanned again
    from calnav.envs.scene import Scene
    from calnav.envs.scene_files import save_atomic

    old = Scene.load(path)
    old.meta.pop("trajectory_version")
    save_atomic(old, path)
    scenes.clear_scene_lru()
    with pytest.warns(UserWarning, match=r"holds another scene \(trajectory_version None, expected"):
        load_scene("house_val_0000", cfg)
    assert len(scanned) == 6


def test_a_converted_ply_cache_of_another_file_is_converted_again(tmp_path, isolated_cache):
    """The converted-PLY cache records the PLY (path and stat key) it came from."""
    import shutil

    d = tmp_path / "scans"
    d.mkdir()
    _write_scan(d / "a.ply")
    _write_scan(d / "b.ply", up_axis="y")
    (d / "labels.json").write_text(json.dumps(LABEL_MAP))
    (d / "b.labels.json").write_text(json.dumps({"label_map": LABEL_MAP, "up_axis": "y"}))
    cfg = DatasetConfig(scene_dir=str(d))
    load_scene("a", cfg), load_scene("b", cfg)
    cached = {p.name.split("_")[1]: p for p in (isolated_cache / "scenes").glob("user_*.npz")}
    shutil.copy(cached["b"], cached["a"])
    scenes.clear_scene_lru()
    with pytest.warns(UserWarning, match=r"holds another scene \(converted_from "):
        assert load_scene("a", cfg).name == "a"


def test_caches_made_from_scans_carry_the_scan_versions(monkeypatch):
    """A scan's identity, and the keys of the training frames and episodes made from scans, hold
    the scanner and trajectory versions; clean caches keep their keys when either moves."""
    import dataclasses

    from calnav.envs import trajectories
    from calnav.envs.config import EnvConfig
    from calnav.envs.episodes import dataset_key
    from calnav.eval.sections import SegDataConfig
    from calnav.eval.segmenter.data import cache_path

    env = EnvConfig()
    scanned = dataclasses.replace(env, dataset=dataclasses.replace(env.dataset, style="scanned"))
    spec = HouseSpec()
    identity = scenes.scanned_identity("house_test_0000", 1, spec, env.dataset)
    assert identity["trajectory_version"] == trajectories.TRAJECTORY_VERSION

    def keys():
        train = cache_path(env, SegDataConfig(), "train", 16, 0, False, rebalance=True)    # half its frames from scans
        clean_eval = cache_path(env, SegDataConfig(), "test", 16, 0, False)
        return (dataset_key(env), dataset_key(scanned), train, clean_eval,
                cache_path(scanned, SegDataConfig(), "test", 16, 0, False))

    before = keys()
    monkeypatch.setattr(trajectories, "TRAJECTORY_VERSION", trajectories.TRAJECTORY_VERSION + 1)
    after = keys()
    assert scenes.scanned_identity("house_test_0000", 1, spec, env.dataset) != identity
    assert [a == b for a, b in zip(before, after)] == [True, False, False, True, False]
