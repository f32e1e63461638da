"""``calnav check-scene``: what the simulator makes of a user scan, a calnav house or a directory
of scenes, and the one-line refusals of scenes that cannot be used."""
from __future__ import annotations

import json

import pytest

from calnav.envs.primitives import MeshBuilder
from calnav.eval.cli import main
from tests.envs.worlds import floor_patch, scan_like, sofa_step_house


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("scenes")
    sofa_step_house().save(root / "apartment.npz")
    b = MeshBuilder("closet")     # 0.6 x 0.6 m of floor: nothing left after the radius erosion
    floor_patch(b, 0, 0, 0.6, 0.6)
    b.add_box((0.3, 0.3, 0.45), (0.2, 0.2, 0.9), "chair", b.new_instance(), (60, 90, 160))
    (root / "bad").mkdir()
    scan_like(b, "closet").save(root / "bad" / "closet.npz")
    return root


def test_check_a_user_scan(scene_dir, tmp_path, capsys):
    out = tmp_path / "check"
    assert main(["check-scene", str(scene_dir / "apartment.npz"), "--output", str(out), "--episodes", "6"]) == 0
    text = capsys.readouterr().out
    assert "walkable floor" in text and "islands: 1 kept" in text and "episodes: 6 generated" in text
    assert f"results: {out}/report.md, report.json, apartment.png, apartment.rrd\n" in text and "<scene>" not in text
    report = json.loads((out / "report.json").read_text())["scenes"][0]
    assert report["scene_id"] == "apartment" and report["generation"]["kept"] == 6
    assert report["figures"]["navigable_m2"] > 10 and report["figures"]["floor_above_p95_m"] == pytest.approx(0.035, abs=0.01)
    assert (out / "apartment.png").stat().st_size > 10_000
    from calnav.common.rerun_io import read_columns

    assert {"/world/mesh", "/world/navmesh", "/world/starts"} <= set(read_columns(out / "apartment.rrd"))


def test_unusable_scenes_are_reported_and_refused(scene_dir, tmp_path, capsys):
    out = tmp_path / "bad_check"
    assert main(["check-scene", str(scene_dir / "bad"), "--output", str(out)]) == 2
    captured = capsys.readouterr()
    assert "cannot be used" in captured.out and "no navigable area" in captured.out
    assert f"results: {out}/report.md, report.json\n" in captured.out   # no picture was drawn, none is listed
    err = captured.err.strip()
    assert "\n" not in err and "1 of 1 scenes cannot be used" in err and "closet" in err
    assert (out / "report.md").exists()
    # a run on such a scene directory stops before writing anything
    run = tmp_path / "run"
    assert main(["objectnav", "--agent", "oracle", "--episodes", "1", "--output", str(run),
                 f"env.dataset.scene_dir={scene_dir / 'bad'}"]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]   # (after the generation progress bar)
    assert last.startswith("calnav objectnav: error: scene 'closet' has no navigable area") and not run.exists()


def test_bad_target(tmp_path, capsys):
    assert main(["check-scene", "no_such_thing", "--output", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "neither a scene file" in err and "house_val_0003" in err and not (tmp_path / "x").exists()


def test_an_hm3d_glb_file_is_a_target(tmp_path, capsys, monkeypatch):
    """check-scene reads a .glb as every command does (envs.scene_files), by the scene's id; a
    semantic mesh or a damaged .semantic.txt is refused in one line naming the file (an edit of
    the .semantic.txt alone is read again: the scene read in memory is keyed by every file it
    is read from)."""
    from tests.envs.test_scene_files_hm3d import FLOOR_HEX, write_scene

    monkeypatch.setenv("CALNAV_CACHE", str(tmp_path / "cache"))
    glb = write_scene(tmp_path / "hm3d" / "00001-scn")
    main(["check-scene", str(glb), "--output", str(tmp_path / "c"), "--episodes", "1"])
    captured = capsys.readouterr()
    assert "a scene file must be" not in captured.err
    assert json.loads((tmp_path / "c" / "report.json").read_text())["scenes"][0]["scene_id"] == "scn"
    assert "walkable floor" in captured.out
    assert main(["check-scene", str(glb.with_name("scn.semantic.glb")), "--output", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "is an HM3D semantic mesh, not a scene: load scn.glb" in err
    txt = glb.with_name("scn.semantic.txt")
    txt.write_text(txt.read_text() + f'9,{FLOOR_HEX},"wall",0\n')
    assert main(["check-scene", str(glb), "--output", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"scn.semantic.txt line 4: colour {FLOOR_HEX} is listed twice" in err
