"""HM3D scenes read from GLBs built here per the glTF spec (pygltflib, not calnav's writer): the
semantic txt grammar, instance colours from a semantic texture (hand-computed texel look-ups)
and from vertex colours (linear -> sRGB), frames (config, habitat's default, y-up, upside
down), missing semantics and undecodable colours, discovery and the converted-scene cache."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from calnav.envs import scenes
from calnav.envs.config import DatasetConfig
from calnav.envs.hm3d import load_hm3d_scene, read_semantic_txt
from calnav.envs.scene import Scene, SceneError
from calnav.envs.scene_files import check_scene_usable, load_scene_file
from calnav.envs.semantics import CLASS_ID, VOID

from .gltf_files import Image, Prim, box_chair, floor_quad, hm3d_config, png, semantic_txt, to_y_up, write_glb

FLOOR_C, CHAIR_C = (0x40, 0x35, 0xBC), (0xE0, 0x10, 0x20)
FLOOR_HEX, CHAIR_HEX = "4035BC", "E01020"
FLOOR_Z = 1.3   # the file's floor height, metres


@pytest.fixture(autouse=True)
def isolated_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("CALNAV_CACHE", str(tmp_path / "cache"))
    scenes.clear_scene_lru()
    yield tmp_path / "cache"
    scenes.clear_scene_lru()


def _geometry(z: float = FLOOR_Z):
    fv, ft, fuv = floor_quad(z=z)
    cv, ct = box_chair(center=(0.5, 0.5, z + 0.25))
    return fv, ft, fuv, cv, ct


def write_scene(folder, sid="scn", colour_tex=True, semantic="texture", y_up=False, txt_rows=None,
                basis=False, semantic_files=True):
    """An HM3D scene folder: a 4 x 4 m floor (colour texture) and a 0.5 m box chair (red factor);
    the semantic GLB carries the instance colours as a texture (floor uv in the left half, the
    chair's at texel (3, 0)) or as COLOR_0 linear floats."""
    folder.mkdir(parents=True, exist_ok=True)
    fv, ft, fuv, cv, ct = _geometry()
    conv = to_y_up if y_up else (lambda v: v)
    tex = np.array([[[200, 10, 10], [10, 200, 10]], [[10, 10, 200], [250, 250, 250]]], np.uint8)
    image = Image(b"not really basis" if basis else png(tex), mime="image/ktx2" if basis else "image/png",
                  extension="KHR_texture_basisu" if basis else None)
    write_glb(folder / f"{sid}.{'basis.' if basis else ''}glb",
              [Prim(conv(fv), ft, uv=fuv, image=0 if colour_tex else None), Prim(conv(cv), ct, factor=(0.8, 0.1, 0.1, 1))],
              [image] if colour_tex else [])
    if not semantic_files:
        return folder / f"{sid}.{'basis.' if basis else ''}glb"
    if semantic == "texture":
        sem = np.zeros((4, 4, 3), np.uint8)
        sem[:, :2], sem[:, 2:] = FLOOR_C, CHAIR_C
        chair_uv = np.full((len(cv), 2), (3.5 / 4, 0.5 / 4))
        write_glb(folder / f"{sid}.semantic.glb", [Prim(conv(fv), ft, uv=fuv * [0.5, 1.0], image=0),
                                                  Prim(conv(cv), ct, uv=chair_uv, image=1)],
                  [Image(png(sem)), Image(png(sem))])
    else:
        def linear(rgb):   # sRGB -> linear, written out here independently of calnav's helper
            s = np.asarray(rgb, float) / 255.0
            return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)
        write_glb(folder / f"{sid}.semantic.glb", [Prim(conv(fv), ft, colour=np.tile(linear(FLOOR_C), (4, 1))),
                                                  Prim(conv(cv), ct, colour=np.tile(linear(CHAIR_C), (8, 1)))])
    semantic_txt(folder / f"{sid}.semantic.txt", txt_rows or [(1, FLOOR_HEX, "floor", 0), (7, CHAIR_HEX, "chair", 0)])
    return folder / f"{sid}.{'basis.' if basis else ''}glb"


def _check_room(s: Scene):
    assert len(s.triangles) == 2 + 12
    assert (s.tri_class[:2] == CLASS_ID["floor"]).all() and (s.tri_class[2:] == CLASS_ID["chair"]).all()
    assert (s.tri_instance[:2] == 1).all() and (s.tri_instance[2:] == 7).all()     # the txt's ids
    assert s.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-5)
    assert s.meta["floor_offset_m"] == pytest.approx(FLOOR_Z, abs=1e-5)
    assert s.vertices[:, 2].max() == pytest.approx(0.5, abs=1e-5)


# ------------------------------------------------------------------------------ the txt
def test_semantic_txt_grammar(tmp_path):
    p = tmp_path / "a.semantic.txt"
    p.write_text('HM3D Semantic Annotations\n1,4035BC,"ceiling corridor",2\n\n2,E01020,"kitchen cabinet, upper",-1\n'
                 ' 3 , 00FF00 , "chair" , 4 \n')
    objs = read_semantic_txt(p)
    assert objs[0x4035BC].name == "ceiling corridor" and objs[0x4035BC].region == 2
    assert objs[0xE01020].name == "kitchen cabinet, upper" and objs[0xE01020].id == 2 and objs[0xE01020].region == -1
    assert objs[0x00FF00].id == 3
    p.write_text("Some other header\n1,4035BC,\"x\",0\n")
    with pytest.raises(SceneError, match="first line must be 'HM3D Semantic Annotations'"):
        read_semantic_txt(p)
    p.write_text('HM3D Semantic Annotations\n1,4035BC,chair,0\n')
    with pytest.raises(SceneError, match=r'line 2: expected id,RRGGBB,"raw name",region_id'):
        read_semantic_txt(p)
    p.write_text('HM3D Semantic Annotations\n1,4035BC,"a",0\n2,4035BC,"b",0\n')
    with pytest.raises(SceneError, match="line 3: colour 4035BC is listed twice"):
        read_semantic_txt(p)


# ---------------------------------------------------------------------- semantic colours
def test_texture_semantics_and_colours(tmp_path):
    s = load_hm3d_scene(write_scene(tmp_path / "00000-scn"))
    _check_room(s)
    assert s.meta["semantic_source"] == "texture" and not s.meta.get("rgb_unavailable")
    assert s.textured and s.tri_material[:2].tolist() == [0, 0] and (s.tri_material[2:] == -1).all()
    np.testing.assert_array_equal(s.textures[0][0, 1], [10, 200, 10])
    np.testing.assert_array_equal(s.tri_albedo[2], [204, 26, 26])       # the chair's base colour factor
    assert s.meta["lighting"] == "baked" and s.meta["closed_solids"] is True


def test_texel_majority_and_centroid_tie_break(tmp_path):
    """Floor quad with uv over the whole 4 x 4 semantic texture. Triangle 0 (corners uv (0,1),
    (1,1), (1,0)) samples (1/3, 5/6), (5/6, 5/6), (5/6, 1/3) -> texels (x, y) (1, 3), (3, 3), (3, 1);
    triangle 1 (uv (0,1), (1,0), (0,0)) samples (1/6, 2/3), (2/3, 1/6), (1/6, 1/6) -> (0, 2), (2, 0),
    (0, 0), centroid (1/3, 1/3) -> (1, 1)."""
    fv, ft, fuv = floor_quad()
    sem = np.zeros((4, 4, 3), np.uint8)
    sem[:, :] = (1, 1, 1)                                  # id 1, floor
    sem[3, 3] = sem[1, 3] = (2, 2, 2)                      # triangle 0: 2 of 3 samples -> id 2
    sem[2, 0], sem[0, 2], sem[0, 0], sem[1, 1] = (3, 3, 3), (4, 4, 4), (5, 5, 5), (6, 6, 6)   # all differ -> centroid
    d = tmp_path / "s"
    d.mkdir()
    write_glb(d / "s.glb", [Prim(fv, ft)])
    write_glb(d / "s.semantic.glb", [Prim(fv, ft, uv=fuv, image=0)], [Image(png(sem))])
    semantic_txt(d / "s.semantic.txt", [(i, f"{i:02X}" * 3, "floor", 0) for i in range(1, 7)])
    s = load_hm3d_scene(d / "s.glb")
    assert s.tri_instance.tolist() == [2, 6]


def test_vertex_colour_semantics_are_converted_linear_to_srgb(tmp_path):
    s = load_hm3d_scene(write_scene(tmp_path / "v", semantic="vertex"))
    _check_room(s)
    assert s.meta["semantic_source"].startswith("vertex colours")


def test_normalized_byte_vertex_colours_match_after_srgb(tmp_path):
    """COLOR_0 as normalized bytes b: habitat-sim matches round(255 srgb(b / 255)), not b."""
    fv, ft, _ = floor_quad()
    b = np.array([40, 40, 40], np.uint8)
    s_val = b / 255.0
    s_val = np.where(s_val <= 0.0031308, 12.92 * s_val, 1.055 * s_val ** (1 / 2.4) - 0.055)
    expect = "".join(f"{int(round(x * 255)):02X}" for x in s_val)        # 6E6E6E, not 282828
    d = tmp_path / "b"
    d.mkdir()
    write_glb(d / "b.glb", [Prim(fv, ft)])
    write_glb(d / "b.semantic.glb", [Prim(fv, ft, colour=np.tile(b, (4, 1)))])
    semantic_txt(d / "b.semantic.txt", [(5, expect, "rug", 0)])
    s = load_hm3d_scene(d / "b.glb")
    assert expect == "6E6E6E" and (s.tri_class == CLASS_ID["floor"]).all() and (s.tri_instance == 5).all()


def test_a_colour_not_in_the_txt_is_refused(tmp_path):
    path = write_scene(tmp_path / "u", txt_rows=[(1, FLOOR_HEX, "floor", 0)])
    with pytest.raises(SceneError, match=rf"semantic colours {CHAIR_HEX} \(12 faces\) are not in .*u/scn.semantic.txt"):
        load_hm3d_scene(path)


def test_unannotated_and_unmapped_names_are_void_and_label_maps_apply(tmp_path):
    rows = [(1, FLOOR_HEX, "floor", 0), (7, CHAIR_HEX, "spaceship, small", 0)]
    path = write_scene(tmp_path / "hm3d" / "val" / "00000-scn", txt_rows=rows)
    s = load_hm3d_scene(path)
    assert (s.tri_class[2:] == VOID).all() and (s.tri_instance[2:] == -1).all()
    (tmp_path / "hm3d" / "labels.json").write_text(json.dumps({"Spaceship, small": "couch"}))
    s = load_hm3d_scene(path, root=tmp_path / "hm3d")
    assert (s.tri_class[2:] == CLASS_ID["sofa"]).all() and s.meta["label_map_file"].endswith("hm3d/labels.json")


# ------------------------------------------------------------------------------ frames
def test_frames_config_default_y_up_and_upside_down(tmp_path):
    root = tmp_path / "hm3d"
    z_up = write_scene(root / "val" / "00000-scn")
    hm3d_config(root / "hm3d_annotated_basis.scene_dataset_config.json")
    a = load_hm3d_scene(z_up, root=root)
    assert a.meta["frame"]["source"].endswith("hm3d_annotated_basis.scene_dataset_config.json")
    b = load_hm3d_scene(write_scene(tmp_path / "plain" / "scn"))           # no config: habitat's .glb default
    assert "habitat-sim's default" in b.meta["frame"]["source"]
    np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-6)
    _check_room(a)
    y_up = write_scene(tmp_path / "yup" / "scn", y_up=True)
    with pytest.raises(SceneError, match=r'y-up read as z-up: its labelled floor is not horizontal \(it faces the y axis\).*'
                                         r'"up": \[0.0, 1.0, 0.0\], "front": \[0.0, 0.0, -1.0\]'):
        load_scene_file(y_up)
    cfg = hm3d_config(tmp_path / "yup.scene_dataset_config.json", up=(0, 1, 0), front=(0, 0, -1))
    c = load_hm3d_scene(y_up, config=cfg)
    np.testing.assert_allclose(c.vertices, a.vertices, atol=1e-5)
    hm3d_config(root / "hm3d_annotated_basis.scene_dataset_config.json", up=(0, 0, -1), front=(0, 1, 0))
    with pytest.raises(SceneError, match=r'read with up \[0.0, 0.0, -1.0\] from .*: upside down \(z flipped\): its labelled '
                                         r'furniture or ceiling lies below its floor; .*"up": \[0.0, 0.0, 1.0\]'):
        load_scene_file(z_up, root=root)


# ----------------------------------------------------------- missing semantics, no colour
def test_missing_semantics_load_for_geometry_and_are_refused_by_gt(tmp_path):
    path = write_scene(tmp_path / "m", semantic_files=False)
    s = load_scene_file(path)
    assert (s.tri_class == VOID).all() and "scn.semantic.glb and scn.semantic.txt not found" in s.meta["semantics_unavailable"]
    check_scene_usable(s, needs_rgb=True)
    with pytest.raises(SceneError, match=r"the gt segmenter needs ground-truth semantics, which scene 'scn' lacks: .*not found"):
        check_scene_usable(s, needs_semantics=True, what="the gt segmenter")
    with pytest.raises(SceneError, match="every face is void"):   # only a scene that says why may be unlabelled
        Scene(name="x", vertices=s.vertices, triangles=s.triangles, tri_class=s.tri_class, tri_instance=s.tri_instance,
              tri_albedo=s.tri_albedo, tri_texture=s.tri_texture)


def test_basis_textures_load_without_colour_and_the_glb_release_wins(tmp_path):
    d = tmp_path / "00000-scn"
    basis = write_scene(d, basis=True)
    s = load_scene_file(basis)
    assert not s.textured and "Basis Universal / KTX2 textures cannot be decoded here; use the scene's .glb release" \
        in s.meta["rgb_unavailable"]
    _check_room(s)
    with pytest.raises(SceneError, match=r"needs RGB, which scene 'scn' lacks: .*scn.basis.glb: Basis Universal"):
        check_scene_usable(s, needs_rgb=True)
    write_scene(d)                                   # the plain .glb beside it: used for colour
    s = load_scene_file(basis)
    assert s.textured and not s.meta.get("rgb_unavailable") and s.meta["render_file"].endswith("scn.glb")


def test_bad_files_are_refused(tmp_path):
    path = write_scene(tmp_path / "b")
    with pytest.raises(SceneError, match="is an HM3D semantic mesh, not a scene: load scn.glb"):
        load_scene_file(path.with_name("scn.semantic.glb"))
    with pytest.raises(SceneError, match=r"unknown scene file type '.obj'; scene files are .npz .*\.ply .*\.glb"):
        load_scene_file(tmp_path / "x.obj")
    (tmp_path / "b" / "bad.glb").write_bytes(b"glTF" + (2).to_bytes(4, "little") + (4000).to_bytes(4, "little")
                                              + (900).to_bytes(4, "little") + b"JSON" + b"{}" * 20)
    with pytest.raises(SceneError, match="bad.glb: .*truncated"):
        load_scene_file(tmp_path / "b" / "bad.glb")
    (tmp_path / "b" / "junk.glb").write_bytes(b"hello")
    with pytest.raises(SceneError, match="not a binary glTF file"):
        load_scene_file(tmp_path / "b" / "junk.glb")


# --------------------------------------------------------------------- discovery, cache
def test_hm3d_tree_discovery_split_folders_and_cache(tmp_path, isolated_cache):
    root = tmp_path / "scene_datasets" / "hm3d"
    write_scene(root / "val" / "00800-aaa", sid="aaa")
    write_scene(root / "minival" / "00800-aaa", sid="aaa")
    write_scene(root / "train" / "00001-bbb", sid="bbb", basis=True)
    write_scene(root / "train" / "00001-bbb", sid="bbb")
    hm3d_config(root / "hm3d_annotated_basis.scene_dataset_config.json")
    cfg = DatasetConfig(scene_dir=str(root))
    assert scenes.split_scene_ids("val", cfg) == ["aaa"] and scenes.split_scene_ids("train", cfg) == ["bbb"]
    b = scenes.load_scene("bbb", cfg)
    assert b.name == "bbb" and b.textured
    whole = DatasetConfig(scene_dir=str(tmp_path / "scene_datasets"))
    assert scenes.split_scene_ids("test", whole) == ["aaa", "bbb"]
    a = scenes.load_scene("aaa", whole)
    assert "minival" in a.meta["source"]                        # the first in path order
    cached = sorted((isolated_cache / "scenes").glob("user_*.npz"))
    assert len(cached) == 2
    scenes.clear_scene_lru()
    again = load_scene_file(root / "train" / "00001-bbb" / "bbb.basis.glb", root=root)
    np.testing.assert_array_equal(again.tri_class, b.tri_class)
    for name in ("tri_uv", "tri_material", "texture_wrap"):
        np.testing.assert_array_equal(getattr(again, name), getattr(b, name))
    np.testing.assert_array_equal(again.textures[0], b.textures[0])
    aaa_cache = next(p for p in cached if p.name.startswith("user_aaa_"))
    bbb_cache = next(p for p in cached if p.name.startswith("user_bbb_"))
    shutil.copy(bbb_cache, aaa_cache)
    scenes.clear_scene_lru()
    with pytest.warns(UserWarning, match=r"holds another scene \(converted_from "):
        assert scenes.load_scene("aaa", whole).name == "aaa"


def test_the_scene_dataset_config_an_episode_names_frames_its_scene(tmp_path, isolated_cache):
    """An episode's ``scene_dataset_config`` (habitat-lab's key, resolved under scene_dir as a
    scene id is) frames its scene: a y-up scene with no config above it is refused as y-up read
    as z-up, and loads through the y-up config its episodes name; the key survives a placed
    content file."""
    from calnav.envs.episode_cache import _PARSED, cached_episodes, sidecar_path
    from calnav.envs.episode_files import ObjectNavEpisode, episodes_from_habitat, episodes_to_habitat, write_json_gz

    scene_dir = tmp_path / "scene_datasets"
    y_up = write_scene(scene_dir / "hm3d" / "val" / "00000-scn", y_up=True)
    z_up = load_hm3d_scene(write_scene(tmp_path / "plain" / "scn"))
    (scene_dir / "configs").mkdir()
    hm3d_config(scene_dir / "configs" / "yup.scene_dataset_config.json", up=(0, 1, 0), front=(0, 0, -1))
    cfg = DatasetConfig(scene_dir=str(scene_dir), data_path=str(tmp_path / "{split}.json.gz"))
    sid = "hm3d/val/00000-scn/scn.glb"
    with pytest.raises(SceneError, match="y-up read as z-up"):
        scenes.load_scene(sid, cfg)
    named = "./data/scene_datasets/configs/yup.scene_dataset_config.json"
    scene = scenes.load_scene(sid, cfg, dataset_config=named)
    assert scene.meta["frame"]["source"].endswith("yup.scene_dataset_config.json") and y_up.is_file()
    np.testing.assert_allclose(scene.vertices, z_up.vertices, atol=1e-5)
    ep = ObjectNavEpisode("0", sid, np.zeros(2), [0.0, 0.0, 0.0, 1.0], "chair", 1.0, 1.0, scene_dataset_config=named)
    data = episodes_to_habitat([ep])
    data["goals_by_category"] = {"scn.glb_chair": []}
    assert episodes_from_habitat(data)[0].scene_dataset_config == named
    content = tmp_path / "placed" / "content" / "scn.json.gz"   # a placed content file and its parsed sidecar
    content.parent.mkdir(parents=True)
    write_json_gz(content, data)
    assert cached_episodes(content)[0].scene_dataset_config == named
    _PARSED.clear()
    assert sidecar_path(content).is_file() and cached_episodes(content)[0].scene_dataset_config == named
