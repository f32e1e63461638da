"""habitat-lab ObjectNav episode files read as habitat-lab reads them (envs.episode_datasets).

The files here are written by hand in habitat-lab's schema (``ObjectNavDatasetV1``: a split
file with the category maps, per-scene content files, goals by ``<scene basename>_<category>``);
tests/eval/habitat/ checks the same reader on files habitat-lab's own classes wrote."""
import gzip
import json

import numpy as np
import pytest

from calnav.envs.episode_datasets import (dataset_files, read_dataset, resolve_scene, scene_candidates,
                                          scene_name)

HM3D_CATEGORIES = {"chair": 0, "bed": 1, "plant": 2, "toilet": 3, "tv_monitor": 4, "sofa": 5}


def _goal(object_id, category, x, z, view_points):
    return {"object_id": object_id, "object_category": category, "position": [x, 0.5, z],
            "view_points": [{"agent_state": {"position": list(p), "rotation": [0, 0, 0, 1]}, "iou": 0.1}
                            for p in view_points]}


def _episode(eid, scene_id, category, start, yaw_q=(0.0, 0.0, 0.0, 1.0)):
    return {"episode_id": eid, "scene_id": scene_id, "start_position": list(start), "start_rotation": list(yaw_q),
            "object_category": category, "info": {"geodesic_distance": 3.5}, "goals": []}


def _write(path, data):
    path.parent.mkdir(parents=True, exist_ok=True)
    with gzip.open(path, "wt") as f:
        json.dump(data, f)


def _hm3d_dataset(root, split="val", split_episodes=()):
    """An HM3D-like layout: data/datasets/objectnav/hm3d/v1/{split}/{split}.json.gz + content/."""
    base = root / "objectnav" / "hm3d" / "v1" / split
    _write(base / f"{split}.json.gz", {"episodes": list(split_episodes), "category_to_task_category_id": HM3D_CATEGORIES,
                                       "category_to_scene_annotation_category_id": HM3D_CATEGORIES})
    for scene, n in (("BBB", 2), ("AAA", 3)):   # written out of order: habitat-lab sorts the files
        sid = f"hm3d/{split}/0080{0 if scene == 'AAA' else 1}-{scene}/{scene}.basis.glb"
        _write(base / "content" / f"0080{0 if scene == 'AAA' else 1}-{scene}.json.gz", {
            "episodes": [_episode(str(i), sid, "chair" if i % 2 == 0 else "bed", (1.0 + i, 0.0, -2.0))
                         for i in range(n)],
            "goals_by_category": {f"{scene}.basis.glb_chair": [_goal(7, "chair", 3.0, -4.0, [(3.0, 0.0, -3.0)])],
                                  f"{scene}.basis.glb_bed": [_goal(9, "bed", 5.0, -1.0, [(4.0, 0.1, -1.0),
                                                                                        (5.0, 0.0, 0.0)])]}})
    return str(root / "objectnav" / "hm3d" / "v1" / "{split}" / "{split}.json.gz")


def test_episodes_come_in_habitat_labs_order_with_their_goals(tmp_path):
    data_path = _hm3d_dataset(tmp_path)
    ds = read_dataset(data_path, "val")
    # content files sorted by name (00800-AAA before 00801-BBB), each in file order
    assert [(scene_name(e.scene_id), e.episode_id) for e in ds.episodes] == [
        ("AAA", "AAA:0"), ("AAA", "AAA:1"), ("AAA", "AAA:2"), ("BBB", "BBB:0"), ("BBB", "BBB:1")]
    assert ds.source.category_names == ("chair", "bed", "plant", "toilet", "tv_monitor", "sofa")
    ep = ds.episodes[1]
    assert ep.object_category == "bed" and [g.object_id for g in ep.goals] == [9]
    # Habitat's (x, y up, z) is calnav's (x, -z) on the floor
    np.testing.assert_allclose(ep.start_position, [2.0, 2.0])
    np.testing.assert_allclose(ep.goals[0].view_points, [[4.0, 1.0], [5.0, 0.0]])
    np.testing.assert_allclose(ep.goals[0].position, [5.0, 1.0, 0.5])
    assert [p.name for p in ds.source.files] == ["00800-AAA.json.gz", "00801-BBB.json.gz"]


def test_split_file_episodes_come_first_and_unique_ids_are_kept(tmp_path):
    sid = "hm3d/val/00802-CCC/CCC.basis.glb"
    own = {**_episode("ccc-a", sid, "chair", (0.0, 0.0, 0.0)),
           "goals": [_goal(1, "chair", 1.0, 1.0, [(1.0, 0.0, 1.0)])]}   # goals in the episode (dedup_goals case)
    data_path = _hm3d_dataset(tmp_path, split_episodes=[own])
    ds = read_dataset(data_path, "val")
    assert ds.episodes[0].episode_id == "CCC:ccc-a" and ds.episodes[0].goals[0].object_id == 1
    assert ds.source.files[0].name == "val.json.gz"


def test_split_placeholder_and_missing_files_are_named(tmp_path):
    data_path = _hm3d_dataset(tmp_path)
    assert dataset_files(data_path, "val").path.name == "val.json.gz"
    with pytest.raises(ValueError, match=r"names no file for split 'test'.*holds: val"):
        dataset_files(data_path, "test")
    with pytest.raises(ValueError, match="data_path is empty"):
        dataset_files("", "val")


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.pop("category_to_task_category_id"), "no category_to_task_category_id"),
    (lambda d: d.update(category_to_task_category_id={"chair": 0, "bed": 2}), r"ids must be 0\.\.1"),
    (lambda d: d.update(category_to_scene_annotation_category_id={"chair": 0}), "name different categories"),
])
def test_bad_category_maps_are_refused(tmp_path, edit, message):
    data_path = _hm3d_dataset(tmp_path)
    split = tmp_path / "objectnav" / "hm3d" / "v1" / "val" / "val.json.gz"
    with gzip.open(split, "rt") as f:
        data = json.load(f)
    edit(data)
    _write(split, data)
    with pytest.raises(ValueError, match=message):
        read_dataset(data_path, "val")


def test_an_episode_of_an_unknown_category_or_without_goals_is_refused(tmp_path):
    data_path = _hm3d_dataset(tmp_path)
    content = tmp_path / "objectnav" / "hm3d" / "v1" / "val" / "content" / "00800-AAA.json.gz"
    with gzip.open(content, "rt") as f:
        data = json.load(f)
    data["episodes"][0]["object_category"] = "fireplace"
    _write(content, data)
    with pytest.raises(ValueError, match=r"no goals_by_category entry 'AAA.basis.glb_fireplace'"):
        read_dataset(data_path, "val")
    data["goals_by_category"]["AAA.basis.glb_fireplace"] = data["goals_by_category"]["AAA.basis.glb_chair"]
    _write(content, data)
    with pytest.raises(ValueError, match=r"category 'fireplace' is not in val.json.gz's category_to_task"):
        read_dataset(data_path, "val")


def _edit_first(episode=None, goal=None):
    def edit(data):
        if episode:
            data["episodes"][0].update(episode)
        if goal:
            data["goals_by_category"]["AAA.basis.glb_chair"][0].update(goal)
    return edit


@pytest.mark.parametrize("edit, message", [
    (_edit_first({"start_position": [float("nan"), 0.0, -2.0]}), r"episode 0: start_position must be 3 finite numbers"),
    (_edit_first({"start_position": [1.0, 0.0]}), r"episode 0: start_position must be 3 finite numbers"),
    (_edit_first({"start_position": ["1", 0, 0]}), r"episode 0: start_position must be 3 finite numbers"),
    (_edit_first({"start_rotation": [0.0, float("inf"), 0.0, 1.0]}), r"start_rotation must be 4 finite numbers"),
    (_edit_first({"start_rotation": [0.0, 2.0, 0.0, 0.5]}), r"start_rotation .* is not a unit quaternion .*norm 2\.06"),
    (_edit_first({"start_rotation": [0.0, 0.0, 0.0, 0.0]}), r"is not a unit quaternion"),
    (_edit_first({"info": {"geodesic_distance": float("nan")}}), r"episode 0: geodesic_distance must be a finite distance >= 0 metres"),
    (_edit_first({"info": {"geodesic_distance": -3.0}}), r"episode 0: geodesic_distance must be a finite distance >= 0 metres, got -3.0"),
    (_edit_first({"info": {"geodesic_distance": "3.5"}}), r"episode 0: geodesic_distance must be a finite distance >= 0 metres"),
    (_edit_first(goal={"position": [float("nan"), 0.5, -4.0]}), r"goal object 7's position must be 3 finite"),
    (_edit_first(goal={"view_points": [{"agent_state": {"position": [3.0, float("nan"), -3.0]}}]}),
     r"a view point's position must be 3 finite numbers"),
])
def test_an_episode_with_a_non_finite_or_malformed_number_is_refused(tmp_path, edit, message):
    """json reads NaN and Infinity, float() reads "1": each is refused naming the file and the key
    (a NaN start failed in the navmesh lookup unnamed; a non-unit rotation ran, exit 0)."""
    data_path = _hm3d_dataset(tmp_path)
    content = tmp_path / "objectnav" / "hm3d" / "v1" / "val" / "content" / "00800-AAA.json.gz"
    with gzip.open(content, "rt") as f:
        data = json.load(f)
    good = json.loads(json.dumps(data))
    edit(data)
    _write(content, data)
    with pytest.raises(ValueError, match=r"damaged episode file .*00800-AAA.json.gz: .*" + message):
        read_dataset(data_path, "val")
    data = good
    ok = [0.0, 0.70711, 0.0, 0.70711]   # a turn rounded to 5 decimals, as habitat-lab writes it, is a unit quaternion
    data["episodes"] = [_episode("0", data["episodes"][1]["scene_id"], "bed", (1.0, 0.0, -2.0), ok)]
    _write(content, data)
    assert read_dataset(data_path, "val").episodes[0].start_rotation == ok


def test_scene_ids_resolve_as_habitat_lab_resolves_them(tmp_path):
    scenes = tmp_path / "scene_datasets"
    glb = scenes / "hm3d" / "val" / "00800-AAA" / "AAA.glb"
    glb.parent.mkdir(parents=True)
    glb.write_bytes(b"glTF")
    # the .basis.glb release is missing: its .glb beside it; habitat-lab's data/scene_datasets/
    # prefix is stripped; v0.2's hm3d_v0.2/ names resolve against hm3d/
    for sid in ("hm3d/val/00800-AAA/AAA.basis.glb", "data/scene_datasets/hm3d/val/00800-AAA/AAA.basis.glb",
                "hm3d_v0.2/val/00800-AAA/AAA.basis.glb", "./hm3d/val/00800-AAA/AAA.glb"):
        assert resolve_scene(sid, str(scenes)) == glb, sid
    basis = glb.with_name("AAA.basis.glb")
    basis.write_bytes(b"glTF")
    assert resolve_scene("hm3d/val/00800-AAA/AAA.basis.glb", str(scenes)) == basis   # present: it wins
    with pytest.raises(ValueError, match=r"scene 'hm3d/val/00899-ZZZ/ZZZ.basis.glb' of the episode file is missing"
                                         r".*tried .*ZZZ.basis.glb, .*ZZZ.glb"):
        resolve_scene("hm3d/val/00899-ZZZ/ZZZ.basis.glb", str(scenes))
    assert len(scene_candidates("mp3d/X/X.glb", str(scenes))) == 2   # under scenes_dir, then as it stands


def test_an_id_habitat_lab_wrote_back_joined_to_a_relative_scenes_dir_resolves(tmp_path, monkeypatch):
    """habitat-lab loads ``calnav/x.glb`` with scenes_dir ``runs/e/scene_datasets`` and writes it
    back as ``runs/e/scene_datasets/calnav/x.glb``: joined again it names nothing, as it stands it
    is the scene (tried last)."""
    monkeypatch.chdir(tmp_path)
    glb = tmp_path / "runs" / "e" / "scene_datasets" / "calnav" / "x.glb"
    glb.parent.mkdir(parents=True)
    glb.write_bytes(b"glTF")
    assert resolve_scene("runs/e/scene_datasets/calnav/x.glb", "runs/e/scene_datasets").resolve() == glb
    assert resolve_scene("calnav/x.glb", "runs/e/scene_datasets").resolve() == glb
    assert scene_name("mp3d/17DRP5sb8fy/17DRP5sb8fy.glb") == "17DRP5sb8fy"


def test_an_episode_id_twice_in_one_scene_is_refused_by_its_file_id(tmp_path):
    data_path = _hm3d_dataset(tmp_path)
    content = tmp_path / "objectnav" / "hm3d" / "v1" / "val" / "content" / "00801-BBB.json.gz"
    with gzip.open(content, "rt") as f:
        data = json.load(f)
    data["episodes"][1]["episode_id"] = "0"
    _write(content, data)
    with pytest.raises(ValueError, match=r"episode id '0' appears twice in the episodes of scene "
                                         r"hm3d/val/00801-BBB/BBB.basis.glb; .*its own episode_id"):
        read_dataset(data_path, "val")
