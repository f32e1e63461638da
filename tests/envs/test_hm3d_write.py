"""calnav houses written in HM3D's layout and read back (same classes per triangle, same instances,
geometry to float32 precision, same depth and labels rendered), the files checked with trimesh
as an independent reader, and the scene dataset config's keys."""
from __future__ import annotations

import json

import numpy as np
import pytest

from calnav.envs import scenes
from calnav.envs.config import DatasetConfig
from calnav.envs.hm3d import read_semantic_txt
from calnav.envs.hm3d_write import write_hm3d_scene, write_scene_dataset_config
from calnav.envs.house import HouseSpec, generate_house
from calnav.envs.render import Camera, Renderer, camera_pose, lit_albedo
from calnav.envs.scene import Scene, Texture
from calnav.envs.scene_files import load_scene_file
from calnav.envs.semantics import CLASS_ID, VOID


@pytest.fixture(autouse=True)
def isolated_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("CALNAV_CACHE", str(tmp_path / "cache"))
    scenes.clear_scene_lru()
    yield
    scenes.clear_scene_lru()


@pytest.fixture(scope="module")
def house():
    return generate_house(1_000_001, HouseSpec())


def test_house_round_trip(tmp_path, house):
    root = tmp_path / "hm3d"
    out = write_hm3d_scene(house, root / "val" / "00000-house0", "house0")
    config = write_scene_dataset_config(root)
    back = load_scene_file(out["glb"], root=root)
    assert back.meta["frame"]["source"] == str(config) and back.meta["semantic_source"] == "texture"
    np.testing.assert_allclose(back.vertices[back.triangles], house.vertices[house.triangles], atol=1e-6)
    np.testing.assert_array_equal(back.tri_class, house.tri_class)
    labelled = house.tri_instance >= 0
    np.testing.assert_array_equal(back.tri_instance[labelled], house.tri_instance[labelled] + 1)
    cam = Camera(160, 120, 79.0)
    room = house.rooms[0]
    pose = camera_pose(((room.xmin + room.xmax) / 2, (room.ymin + room.ymax) / 2), 0.4, 0.88)
    a, b = Renderer(house, cam).render(pose), Renderer(back, cam).render(pose)
    np.testing.assert_array_equal(a.semantic, b.semantic)
    np.testing.assert_allclose(a.depth, b.depth, atol=1e-5)
    hit = a.instance >= 0
    lit = lit_albedo(house)
    tri_of_pixel = {int(i): np.flatnonzero(house.tri_instance == i) for i in np.unique(a.instance[hit])}
    for inst, tris in list(tri_of_pixel.items())[:5]:   # each pixel's colour is one of its object's lit colours
        colours = {tuple(c) for c in lit[tris]}
        assert all(tuple(p) in colours for p in b.rgb[a.instance == inst][:50])


def test_void_faces_and_faces_without_instance(tmp_path):
    v = np.array([[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0], [0, 0, 2], [4, 0, 2]], float)
    t = np.array([[0, 1, 2], [0, 2, 3], [0, 1, 5], [0, 5, 4]])
    s = Scene(name="s", vertices=v, triangles=t, tri_class=[CLASS_ID["floor"], CLASS_ID["floor"], CLASS_ID["wall"], VOID],
              tri_instance=[-1, -1, 3, -1], tri_albedo=np.full((4, 3), 100), tri_texture=np.full(4, Texture.PLAIN))
    out = write_hm3d_scene(s, tmp_path / "s", "s")
    objects = sorted(read_semantic_txt(out["semantic_txt"]).values(), key=lambda o: o.id)
    assert [(o.id, o.name, o.region) for o in objects] == [(4, "wall", -1), (5, "floor", -1)]
    back = load_scene_file(out["glb"])
    assert back.tri_class.tolist() == s.tri_class.tolist() and back.tri_instance.tolist() == [5, 5, 4, -1]


def test_files_read_by_trimesh_and_the_config(tmp_path, house):
    import trimesh

    out = write_hm3d_scene(house, tmp_path / "val" / "00000-h", "h")
    mesh = trimesh.load(out["glb"], force="mesh", process=False)
    np.testing.assert_allclose(mesh.vertices, house.vertices[house.triangles].reshape(-1, 3), atol=1e-6)
    assert mesh.visual.uv.shape == (3 * len(house.triangles), 2)
    side = int(np.ceil(np.sqrt(len(house.triangles))))
    assert mesh.visual.material.baseColorTexture.size == (side, side)
    sem = trimesh.load(out["semantic_glb"], force="mesh", process=False)
    assert sem.visual.uv.shape == mesh.visual.uv.shape
    first = out["semantic_txt"].read_text().splitlines()
    assert first[0] == "HM3D Semantic Annotations" and first[1].count('"') == 2
    doc = json.loads(write_scene_dataset_config(tmp_path).read_text())
    attrs = doc["stages"]["default_attributes"]
    assert attrs["up"] == [0, 0, 1] and attrs["front"] == [0, 1, 0] and attrs["has_semantic_textures"] is True
    assert attrs["semantic_asset"] == "%%CONFIG_NAME_AS_ASSET_FILENAME%%.semantic.glb"
    assert attrs["semantic_descriptor_filename"] == "%%CONFIG_NAME_AS_ASSET_FILENAME%%.semantic.txt"
    assert doc["stages"]["paths"][".glb"] == ["val/00000-h/h.glb"]
    cfg = DatasetConfig(scene_dir=str(tmp_path))
    assert scenes.split_scene_ids("val", cfg) == ["h"]


def test_bad_scene_id_is_refused_before_writing(tmp_path, house):
    with pytest.raises(ValueError, match=r"scene id 'a/b' must be letters, digits, '_' or '-'"):
        write_hm3d_scene(house, tmp_path / "out", "a/b")
    assert not (tmp_path / "out").exists()
