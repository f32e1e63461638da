"""MP3D scenes: a GLB (JPEG texture) with habitat's ``.house`` and ``_semantic.ply`` built here per
their formats; mpcat40 names as calnav classes, labels carried from the semantic mesh's own faces,
the floor shift, and the refusals."""
from __future__ import annotations

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from calnav.envs import scenes
from calnav.envs.config import DatasetConfig
from calnav.envs.mp3d import load_mp3d_scene, read_house
from calnav.envs.scene import SceneError
from calnav.envs.scene_files import load_scene_file, scene_kind
from calnav.envs.semantics import CLASS_ID, VOID

from .gltf_files import Image, Prim, box_chair, floor_quad, jpeg, write_glb

FLOOR_Z = 0.7
HOUSE = """ASCII 1.1
H house_x house 0 0 0 0 0 5 4 1 0 1  0 0 0 0 0  -2 -2 0 2 2 3  0 0 0 0 0
C 0 1 floor 2 floor 0 0 0 0 0
C 1 3 chair 3 chair 0 0 0 0 0
C 2 7 book#shelf 31 shelving 0 0 0 0 0
C 3 9 painting 6 picture 0 0 0 0 0
O 0 0 0  0 0 0  1 0 0  0 1 0  1 1 1  0 0 0 0 0 0 0 0
O 1 0 1  0 0 0  1 0 0  0 1 0  1 1 1  0 0 0 0 0 0 0 0
O 2 0 2  0 0 0  1 0 0  0 1 0  1 1 1  0 0 0 0 0 0 0 0
O 3 0 3  0 0 0  1 0 0  0 1 0  1 1 1  0 0 0 0 0 0 0 0
O 4 0 -1  0 0 0  1 0 0  0 1 0  1 1 1  0 0 0 0 0 0 0 0
"""


@pytest.fixture(autouse=True)
def isolated_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("CALNAV_CACHE", str(tmp_path / "cache"))
    scenes.clear_scene_lru()
    yield
    scenes.clear_scene_lru()


def _parts(z: float):
    fv, ft, fuv = floor_quad(z=z)
    chair = box_chair(center=(0.5, 0.5, z + 0.25))
    shelf = box_chair(center=(-1.0, -1.0, z + 0.6), size=(0.8, 0.3, 1.2))
    picture = box_chair(center=(1.5, -1.5, z + 1.5), size=(0.4, 0.05, 0.3))
    return (fv, ft, fuv), [chair, shelf, picture]


def _semantic_ply(path, z: float, object_ids=(0, 1, 2, 3)):
    """The semantic mesh: the floor split into 8 triangles (not the GLB's 2), the boxes as they are."""
    (fv, _, _), boxes = _parts(z)
    centre = np.array([[0, 0, z]])
    verts = [np.vstack([fv, (fv[[0, 1, 2, 3]] + fv[[1, 2, 3, 0]]) / 2, centre])]
    tris = [np.array([[0, 4, 8], [4, 1, 8], [1, 5, 8], [5, 2, 8], [2, 6, 8], [6, 3, 8], [3, 7, 8], [7, 0, 8]])]
    obj = [np.full(8, object_ids[0])]
    n = len(verts[0])
    for k, (bv, bt) in enumerate(boxes):
        verts.append(bv)
        tris.append(bt + n)
        obj.append(np.full(len(bt), object_ids[k + 1]))
        n += len(bv)
    v = np.vstack(verts)
    vert = np.empty(len(v), [("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    vert["x"], vert["y"], vert["z"] = v.T
    vert["red"] = vert["green"] = vert["blue"] = 128
    t = np.vstack(tris)
    face = np.empty(len(t), [("vertex_indices", "i4", (3,)), ("object_id", "i4")])
    face["vertex_indices"], face["object_id"] = t, np.concatenate(obj)
    PlyData([PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")]).write(str(path))


def write_mp3d(folder, sid="17DRP5sb8fy", house=HOUSE, object_ids=(0, 1, 2, 3), semantic=True):
    folder.mkdir(parents=True, exist_ok=True)
    (fv, ft, fuv), boxes = _parts(FLOOR_Z)
    tex = np.zeros((8, 8, 3), np.uint8)
    tex[:, :] = (90, 140, 200)
    prims = [Prim(fv, ft, uv=fuv, image=0)] + [Prim(bv, bt) for bv, bt in boxes]
    write_glb(folder / f"{sid}.glb", prims, [Image(jpeg(tex), mime="image/jpeg")])
    if semantic:
        (folder / f"{sid}.house").write_text(house)
        _semantic_ply(folder / f"{sid}_semantic.ply", FLOOR_Z, object_ids)
    return folder / f"{sid}.glb"


def test_read_house(tmp_path):
    (tmp_path / "h.house").write_text(HOUSE)
    assert read_house(tmp_path / "h.house") == {0: "floor", 1: "chair", 2: "shelving", 3: "picture", 4: ""}
    (tmp_path / "h.house").write_text("ASCII 1.0\n")
    with pytest.raises(SceneError, match="first line must be 'ASCII 1.1'"):
        read_house(tmp_path / "h.house")
    (tmp_path / "h.house").write_text("ASCII 1.1\nC 0 1 floor\n")
    with pytest.raises(SceneError, match="line 2: malformed C line"):
        read_house(tmp_path / "h.house")
    (tmp_path / "h.house").write_text("ASCII 1.1\nC 0 1 floor 2 floor 0 0 0 0 0\nO 0 0 3 0 0 0\n")
    with pytest.raises(SceneError, match="object 0 has category 3, but the file lists 1 categories"):
        read_house(tmp_path / "h.house")



@pytest.mark.parametrize("edit, message", [
    (lambda h: h + "O 1 0 3  0 0 0  1 0 0  0 1 0  1 1 1  0 0 0 0 0 0 0 0\n", r"line 12: object 1 is listed twice"),
    (lambda h: h.replace("C 1 3 chair", "C 0 3 chair"), r"line 4: category index 0 where 1 comes next"),
    (lambda h: h.replace("C 1 3 chair", "C 2 3 chair").replace("C 2 7 book", "C 1 7 book"),
     r"line 4: category index 2 where 1 comes next"),
])
def test_a_house_object_or_category_listed_twice_is_refused(tmp_path, edit, message):
    """Objects name their category by its C line's index: a repeated object or a category out of
    its place labelled some faces with another class, silently."""
    (tmp_path / "h.house").write_text(edit(HOUSE))
    with pytest.raises(SceneError, match=r"h.house " + message):
        read_house(tmp_path / "h.house")

def test_mp3d_scene_classes_instances_colour_and_floor(tmp_path):
    path = write_mp3d(tmp_path / "mp3d" / "17DRP5sb8fy")
    assert scene_kind(path) == "mp3d"
    s = load_scene_file(path)
    assert s.meta["format"] == "mp3d" and s.meta["unmatched_faces"] == 0
    assert (s.tri_class[:2] == CLASS_ID["floor"]).all() and (s.tri_instance[:2] == 0).all()
    assert (s.tri_class[2:14] == CLASS_ID["chair"]).all() and (s.tri_instance[2:14] == 1).all()
    assert (s.tri_class[14:26] == CLASS_ID["shelf"]).all() and (s.tri_instance[14:26] == 2).all()   # shelving
    assert (s.tri_class[26:] == VOID).all() and (s.tri_instance[26:] == -1).all()                  # picture
    assert s.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-5) and s.meta["floor_offset_m"] == pytest.approx(FLOOR_Z)
    assert s.textured and abs(int(s.textures[0][4, 4, 2]) - 200) <= 3                              # JPEG decoded
    assert "habitat-sim's default" in s.meta["frame"]["source"]


def test_mp3d_tree_is_discovered(tmp_path):
    write_mp3d(tmp_path / "mp3d" / "17DRP5sb8fy")
    cfg = DatasetConfig(scene_dir=str(tmp_path))
    assert scenes.split_scene_ids("val", cfg) == ["17DRP5sb8fy"]
    assert scenes.load_scene("17DRP5sb8fy", cfg).meta["format"] == "mp3d"


def test_mp3d_refusals_and_missing_semantics(tmp_path):
    path = write_mp3d(tmp_path / "a", object_ids=(0, 1, 2, 9))
    with pytest.raises(SceneError, match=r"object ids \[9\] have no O line in .*a/17DRP5sb8fy.house"):
        load_mp3d_scene(path)
    bare = write_mp3d(tmp_path / "b", semantic=False)
    s = load_mp3d_scene(bare)
    assert (s.tri_class == VOID).all() and "17DRP5sb8fy.house and 17DRP5sb8fy_semantic.ply not found" in \
        s.meta["semantics_unavailable"]
    (tmp_path / "b" / "17DRP5sb8fy.house").write_text(HOUSE)
    vert = np.zeros(3, [("x", "f4"), ("y", "f4"), ("z", "f4")])
    face = np.empty(1, [("vertex_indices", "i4", (3,)), ("segment_id", "i4")])
    face["vertex_indices"], face["segment_id"] = [[0, 1, 2]], [0]
    PlyData([PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")]).write(
        str(tmp_path / "b" / "17DRP5sb8fy_semantic.ply"))
    with pytest.raises(SceneError, match=r"no per-face object_id \(face properties: \['vertex_indices', 'segment_id'\]\)"):
        load_mp3d_scene(bare)
