"""`calnav export-habitat` and the round trip back through ``env.dataset.data_path``: the
exported houses and episodes, read as an HM3D-layout dataset, give calnav's own run episode by
episode (same navmesh, same starts, same goals), and every bad input is one line."""
import gzip
import json

import numpy as np
import pytest

from calnav.eval.cli import main
from tests.conftest import read_records

SMALL = ["env.resolution=64x48", "env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=4", "run.workers=1"]


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp("export")
    assert main(["export-habitat", "--split", "val", "--output", str(out), *SMALL]) == 0
    return out


def _file_args(out) -> list[str]:
    return [f"env.dataset.data_path={out}/datasets/objectnav/calnav/v1/{{split}}/{{split}}.json.gz",
            f"env.dataset.scene_dir={out}/scene_datasets"]


def test_the_export_is_in_hm3d_v02_layout(exported):
    scene = exported / "scene_datasets" / "calnav" / "val" / "00000-house_val_0000"
    assert sorted(p.name for p in scene.iterdir()) == ["house_val_0000.glb", "house_val_0000.semantic.glb",
                                                        "house_val_0000.semantic.txt"]
    assert (exported / "scene_datasets" / "calnav" / "calnav.scene_dataset_config.json").is_file()
    split = exported / "datasets" / "objectnav" / "calnav" / "v1" / "val"
    with gzip.open(split / "val.json.gz", "rt") as f:
        head = json.load(f)
    assert head["episodes"] == [] and head["category_to_task_category_id"]["chair"] == 0
    with gzip.open(split / "content" / "house_val_0000.json.gz", "rt") as f:
        content = json.load(f)
    ep = content["episodes"][0]
    assert ep["scene_id"] == "calnav/val/00000-house_val_0000/house_val_0000.glb"
    assert ep["scene_dataset_config"] == "./data/scene_datasets/calnav/calnav.scene_dataset_config.json"
    assert f"house_val_0000.glb_{ep['object_category']}" in content["goals_by_category"]


def test_read_back_the_oracle_runs_every_episode_as_on_calnavs_own(exported, tmp_path):
    """The exported GLB's navmesh is calnav's own (its winding decides walkability, as in
    habitat-sim; judged by |normal| the ceilings would be the ground), so every episode
    is placed where it was and the oracle takes the same actions."""
    own, back = tmp_path / "own", tmp_path / "back"
    assert main(["objectnav", "--agent", "oracle", "--episodes", "0:4", "--output", str(own), *SMALL]) == 0
    assert main(["objectnav", "--agent", "oracle", "--episodes", "0:4", "--output", str(back), *SMALL,
                 *_file_args(exported)]) == 0
    a, b = read_records(own), read_records(back)
    assert sorted(a) == sorted(b) == [0, 1, 2, 3]
    for i in a:
        assert (a[i]["success"], a[i]["steps"]) == (b[i]["success"], b[i]["steps"]) == (1.0, a[i]["steps"])
        assert b[i]["scene"] == "calnav/val/00000-house_val_0000/house_val_0000.glb"
        assert np.isclose(a[i]["spl"], b[i]["spl"], atol=1e-4)


def test_refused_episodes_are_listed_not_run(exported, tmp_path):
    """An episode whose start a user moved 3 m off the house keeps its index, is listed with its
    reason in summary.json, and the others run."""
    data = tmp_path / "moved"
    split = exported / "datasets" / "objectnav" / "calnav" / "v1" / "val"
    (data / "val" / "content").mkdir(parents=True)
    (data / "val" / "val.json.gz").write_bytes((split / "val.json.gz").read_bytes())
    with gzip.open(split / "content" / "house_val_0000.json.gz", "rt") as f:
        content = json.load(f)
    content["episodes"][1]["start_position"][0] -= 30.0
    with gzip.open(data / "val" / "content" / "house_val_0000.json.gz", "wt") as f:
        json.dump(content, f)
    out = tmp_path / "run"
    assert main(["objectnav", "--agent", "oracle", "--episodes", "0:3", "--output", str(out), *SMALL,
                 f"env.dataset.data_path={data}/{{split}}/{{split}}.json.gz",
                 f"env.dataset.scene_dir={exported}/scene_datasets"]) == 0
    assert sorted(read_records(out)) == [0, 2]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["refused"]["episodes"] == 1 and list(summary["refused"]["indices"]) == ["1"]
    assert summary["refused"]["by_reason"] == {"start off the navmesh": 1}
    assert summary["refused"]["by_scene"] == {"calnav/val/00000-house_val_0000/house_val_0000.glb": 1}


@pytest.mark.parametrize("override, message", [
    ("env.dataset.data_path=/nonexistent/{split}/{split}.json.gz", "names no file for split 'val'"),
    ("env.dataset.scene_dir=/nonexistent", "is missing under env.dataset.scene_dir"),
    ("agent.goal_categories=[chair,bed]", "set agent.goal_categories=[chair,bed,plant,toilet,tv_monitor,sofa]"),
    ("env.dataset.max_snap_m=nan", "env.dataset.max_snap_m"),
])
def test_bad_file_inputs_are_one_line_before_anything_is_written(exported, tmp_path, capsys, override, message):
    out = tmp_path / "run"
    args = [a for a in _file_args(exported) if a.split("=")[0] != override.split("=")[0]]
    assert main(["objectnav", "--episodes", "0:2", "--output", str(out), *SMALL, *args, override]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not out.exists()


def test_a_data_path_needs_a_scene_dir(capsys, tmp_path):
    assert main(["objectnav", "--output", str(tmp_path / "r"), "env.dataset.data_path=x/{split}.json.gz"]) == 2
    assert "needs env.dataset.scene_dir" in capsys.readouterr().err


def test_export_refuses_a_non_empty_output(exported, capsys):
    assert main(["export-habitat", "--output", str(exported), *SMALL]) == 2
    assert "is not empty" in capsys.readouterr().err


def test_a_scene_without_its_semantic_files_is_refused_for_gt(exported, tmp_path, capsys):
    """The gt segmenter reads the semantic annotations; a scene whose semantic files are gone
    is placed again (its files changed) and the run refused, naming the scene and the files."""
    import shutil

    copy = tmp_path / "data"
    shutil.copytree(exported, copy)
    scene = copy / "scene_datasets" / "calnav" / "val" / "00000-house_val_0000"
    for name in ("house_val_0000.semantic.glb", "house_val_0000.semantic.txt"):
        (scene / name).unlink()
    out = tmp_path / "run"
    assert main(["objectnav", "--episodes", "0:2", "--output", str(out), *SMALL, *_file_args(copy)]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "agent.segmenter=gt needs ground-truth semantics, which scene" in err and "semantic" in err
    assert not out.exists()
    # the oracle reads no image: it runs
    assert main(["objectnav", "--agent", "oracle", "--episodes", "0:2", "--output", str(out), *SMALL,
                 *_file_args(copy)]) == 0


def test_a_file_run_fingerprints_its_episode_and_scene_files(exported, tmp_path, capsys):
    """inputs.json names every file of the split (by content) and every file of its scenes (by
    path, size, mtime); a resume after one changed is refused, naming it."""
    import os
    import shutil

    copy = tmp_path / "data"
    shutil.copytree(exported, copy)
    out = tmp_path / "run"
    args = ["objectnav", "--agent", "oracle", "--episodes", "0:1", "--output", str(out), *SMALL, *_file_args(copy)]
    assert main(args) == 0
    inputs = json.loads((out / "inputs.json").read_text())
    assert {"env.dataset.data_path (val.json.gz)", "env.dataset.data_path (house_val_0000.json.gz)",
            "env.dataset.scene_dir (house_val_0000.glb)", "env.dataset.scene_dir (house_val_0000.semantic.txt)"} \
        <= set(inputs)
    txt = copy / "scene_datasets" / "calnav" / "val" / "00000-house_val_0000" / "house_val_0000.semantic.txt"
    os.utime(txt, ns=(txt.stat().st_atime_ns, txt.stat().st_mtime_ns + 10**9))
    capsys.readouterr()
    assert main([*args[:4], "0:2", *args[5:]]) == 2
    assert "house_val_0000.semantic.txt" in capsys.readouterr().err


def test_a_scene_whose_floor_is_not_at_zero_keeps_its_episodes(tmp_path):
    """HM3D's floors lie anywhere in the file's frame; calnav puts the floor at z = 0, so the
    file's heights are moved by the same offset: a house raised 1.4 m, with its episodes at
    y = 1.4 m, places every start where the flat house has it."""
    from dataclasses import replace

    from calnav.envs import habitat_export as hx
    from calnav.envs.episodes import load_split
    from calnav.eval.config import load_config

    cfg = load_config(None, SMALL).env
    episodes = load_split("val", cfg)
    from calnav.envs.scenes import load_scene

    scene = load_scene("house_val_0000", cfg.dataset)
    raised = replace(scene, vertices=scene.vertices + np.array([0.0, 0.0, 1.4], np.float32))
    out = tmp_path / "data"
    hx.write_scene(raised, out, "val", 0, "house_val_0000")
    high = [replace(ep, start_height=1.4, goals=[replace(g, view_point_heights=g.heights() + 1.4) for g in ep.goals])
            for ep in episodes]
    hx.write_episodes(out, "val", ("chair", "bed", "plant", "toilet", "tv_monitor", "sofa"),
                      {"house_val_0000": hx.scene_content(high, "val", 0, "house_val_0000")})
    hx.write_dataset_config(out)
    where = hx.paths(out, "val")
    file_cfg = replace(cfg, dataset=replace(cfg.dataset, data_path=where["data_path"], scene_dir=where["scene_dir"]))
    placed = load_split("val", file_cfg, progress=False)
    assert [ep.refused for ep in placed] == [""] * len(episodes)
    for a, b in zip(episodes, placed):
        np.testing.assert_allclose(a.start_position, b.start_position, atol=1e-9)
        assert abs(b.start_height) < 0.01


def test_a_house_with_storeys_round_trips_its_stairs(tmp_path):
    """A two-storey house exported and read back: its storeys are found from the geometry
    (``envs.storey_detect``), so the navmesh is layered again and the oracle takes the same
    actions, across the stairs too; the records name both storeys."""
    small = ["env.resolution=32x24", "env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=6", "run.workers=1"]
    out, own, back = tmp_path / "data", tmp_path / "own", tmp_path / "back"
    assert main(["export-habitat", "--output", str(out), *small, "env.dataset.storeys=2"]) == 0
    assert main(["objectnav", "--agent", "oracle", "--episodes", "0:6", "--output", str(own), *small,
                 "env.dataset.storeys=2"]) == 0
    assert main(["objectnav", "--agent", "oracle", "--episodes", "0:6", "--output", str(back), *small,
                 *_file_args(out)]) == 0
    a, b = read_records(own), read_records(back)
    for i in a:
        assert (a[i]["success"], a[i]["steps"]) == (b[i]["success"], b[i]["steps"])
        assert (a[i]["start_storey"], a[i]["goal_storey"]) == (b[i]["start_storey"], b[i]["goal_storey"])
    assert any(r["start_storey"] != r["goal_storey"] for r in b.values())


MP3D_21 = ("chair", "table", "picture", "cabinet", "cushion", "sofa", "bed", "chest_of_drawers", "plant", "sink",
           "toilet", "stool", "towel", "tv_monitor", "shower", "bathtub", "counter", "fireplace", "gym_equipment",
           "seating", "clothes")


def test_a_category_the_segmenter_lacks_is_refused_naming_it(exported, tmp_path, capsys):
    """An MP3D-style file (21 categories): with agent.goal_categories set to them, the gt
    segmenter (calnav's classes) is refused, naming the categories it cannot see."""
    split = exported / "datasets" / "objectnav" / "calnav" / "v1" / "val"
    data = tmp_path / "mp3d"
    (data / "val" / "content").mkdir(parents=True)
    for f in (split / "content").iterdir():
        (data / "val" / "content" / f.name).write_bytes(f.read_bytes())
    ids = {c: i for i, c in enumerate(MP3D_21)}
    with gzip.open(data / "val" / "val.json.gz", "wt") as f:
        json.dump({"episodes": [], "category_to_task_category_id": ids,
                   "category_to_scene_annotation_category_id": ids}, f)
    out = tmp_path / "run"
    args = ["objectnav", "--episodes", "0:2", "--output", str(out), *SMALL,
            f"env.dataset.data_path={data}/{{split}}/{{split}}.json.gz", f"env.dataset.scene_dir={exported}/scene_datasets"]
    assert main(args) == 2
    assert "set agent.goal_categories=[chair,table,picture" in capsys.readouterr().err
    assert main([*args, f"agent.goal_categories=[{','.join(MP3D_21)}]"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "cushion" in err and "gym_equipment" in err, err
    assert not out.exists()
