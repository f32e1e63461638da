"""A scene that is no building in metres on its floor is refused as it loads, in one line naming
the fix, before anything sized by its extent is built: upside down, a y-up mesh read as z-up, a
mesh in centimetres or millimetres. Clean, scanned-looking and calnav's own houses pass."""
from __future__ import annotations

import copy
import json
import time

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from calnav.envs.house import HouseSpec, generate_house
from calnav.envs.scene import SceneError
from calnav.envs.scene_files import load_scene_file
from calnav.envs.scene_plausible import check_plausible
from calnav.envs.semantics import CLASS_ID
from calnav.eval.cli import main
from tests.envs.worlds import sofa_step_house, warped_floor_house


@pytest.fixture
def no_grids(monkeypatch):
    """Every navmesh (single-storey or layered) starts with the heightfield raster: refuse to build one."""
    import calnav.envs.navmesh as navmesh

    def refuse(*_args, **_kwargs):
        raise AssertionError("a heightfield was rasterised for an implausible scene")

    monkeypatch.setattr(navmesh, "build_heightfield", refuse)


def _transformed(scene, verts):
    out = copy.deepcopy(scene)
    out.vertices = np.ascontiguousarray(verts, dtype=np.float32)
    return out


def _write_ply(scene, path, verts=None):
    """``scene`` as a labelled PLY (per-face ``label`` = calnav class id, void -1), ``verts`` (V, 3) in place of its own."""
    v = scene.vertices if verts is None else verts
    vert = np.empty(len(v), [("x", "f4"), ("y", "f4"), ("z", "f4")])
    vert["x"], vert["y"], vert["z"] = np.asarray(v).T
    face = np.empty(len(scene.triangles), [("vertex_indices", "O"), ("label", "i4")])
    face["vertex_indices"] = [np.asarray(t, np.int32) for t in scene.triangles]
    face["label"] = scene.tri_class
    PlyData([PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")]).write(str(path))
    return path


def _check_scene_error(target, out, capsys) -> str:
    assert main(["check-scene", str(target), "--output", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "1 of 1 scenes cannot be used" in err
    return err


def test_upside_down_scene_is_refused_before_any_grid(tmp_path, capsys, no_grids):
    house = sofa_step_house()
    flipped = house.vertices * [1.0, 1.0, -1.0]
    _transformed(house, flipped).save(tmp_path / "flipped.npz")
    err = _check_scene_error(tmp_path / "flipped.npz", tmp_path / "check", capsys)
    assert "upside down (z flipped): its labelled furniture or ceiling lies below its floor" in err
    assert "its -z axis is +z, then Scene.save" in err
    # a PLY: the fix is its labels.json's up_axis, and declaring it loads the house on its floor
    (tmp_path / "ply").mkdir()
    ply = _write_ply(house, tmp_path / "ply" / "flipped.ply", flipped)
    with pytest.raises(SceneError, match=r'upside down \(z flipped\).*set "up_axis": "-z" in .*flipped.labels.json'):
        load_scene_file(ply)
    (tmp_path / "ply" / "flipped.labels.json").write_text(json.dumps({"label_map": None, "up_axis": "-z"}))
    s = load_scene_file(ply)
    chair = s.tri_class == CLASS_ID["chair"]
    assert s.vertices[s.triangles[chair]][..., 2].min() == pytest.approx(0.0, abs=1e-5)
    assert s.vertices[s.triangles[chair]][..., 2].max() == pytest.approx(0.9, abs=1e-5)


def test_y_up_mesh_read_as_z_up_names_the_up_axis(tmp_path, capsys, no_grids):
    house = warped_floor_house()
    v = house.vertices
    y_up = np.stack([v[:, 0], v[:, 2], -v[:, 1]], axis=1)   # z-up to y-up: the inverse of up_axis "y"
    ply = _write_ply(house, tmp_path / "yup.ply", y_up)
    err = _check_scene_error(ply, tmp_path / "check", capsys)
    assert "y-up read as z-up: its labelled floor is not horizontal (it faces the y axis)" in err
    assert 'set "up_axis": "y" in' in err and "no reachable, visible instance" not in err
    (tmp_path / "labels.json").write_text(json.dumps({"label_map": None, "up_axis": "y"}))
    (tmp_path / "zup").mkdir()
    z_up = load_scene_file(_write_ply(house, tmp_path / "zup" / "zup.ply"))
    np.testing.assert_allclose(load_scene_file(ply).vertices, z_up.vertices, atol=1e-4)


@pytest.mark.parametrize("scale, unit", [(100.0, "centimetres (scale 0.01)"), (1000.0, "millimetres (scale 0.001)")])
def test_scene_in_centimetres_or_millimetres_is_refused_at_once(tmp_path, capsys, no_grids, scale, unit):
    house = sofa_step_house()
    _transformed(house, house.vertices * scale).save(tmp_path / "big.npz")
    start = time.perf_counter()
    err = _check_scene_error(tmp_path / "big.npz", tmp_path / "check", capsys)
    assert time.perf_counter() - start < 10.0
    assert f"beyond any building (> 200 m across or > 100 m high): its coordinates are likely {unit}" in err
    assert "calnav has no scale setting: convert the file to metres" in err
    (tmp_path / "scans").mkdir()
    ply = _write_ply(house, tmp_path / "scans" / "big.ply", house.vertices * scale)
    with pytest.raises(SceneError, match=rf"likely {unit.split()[0]}.*every vertex coordinate x {1 / scale}"):
        load_scene_file(ply)
    # objectnav meets it in a worker generating episodes: the same one line, nothing written
    run = tmp_path / "run"
    assert main(["objectnav", "--agent", "oracle", "--episodes", "1", "--output", str(run),
                 f"env.dataset.scene_dir={tmp_path / 'scans'}"]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith(f"calnav objectnav: error: {ply}: it is ") and unit in last and not run.exists()


def test_plausible_scenes_pass_and_storeys_upside_down_do_not(tmp_path):
    two_storeys = generate_house(2_000_001, HouseSpec(), storeys=2)
    for scene in (sofa_step_house(), warped_floor_house(), generate_house(2_000_000, HouseSpec()), two_storeys):
        assert check_plausible(scene.vertices, scene.triangles, scene.tri_class) is None, scene.name
    # each storey's furniture hangs below its own floor, though above the lowest floor of the house
    found = check_plausible(two_storeys.vertices * [1.0, 1.0, -1.0], two_storeys.triangles, two_storeys.tri_class)
    assert found is not None and found.up.tolist() == [0.0, 0.0, -1.0]
    flat = sofa_step_house()   # a scan without furniture, ceiling or floor labels cannot tell: it passes
    flat.tri_class[:] = -1
    assert check_plausible(flat.vertices, flat.triangles, flat.tri_class) is None
    s = load_scene_file(_write_ply(sofa_step_house(), tmp_path / "ok.ply"))
    assert s.meta["up_axis"] == "z"
