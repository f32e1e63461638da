"""Image-textured scenes: the texel at a hand-computed pixel, glTF wrap modes, albedo tint,
untextured triangles and scenes unchanged, and the optional arrays' .npz round trip."""
from __future__ import annotations

import numpy as np
import pytest

from calnav.envs.gltf import CLAMP_TO_EDGE, MIRRORED_REPEAT, REPEAT, wrap_texels
from calnav.envs.primitives import box_room_scene
from calnav.envs.render import Camera, Renderer, look_at_pose
from calnav.envs.scene import Scene, SceneError, Texture

A, B, C, D = (200, 10, 10), (10, 200, 10), (10, 10, 200), (250, 250, 250)
TEX = np.array([[A, B], [C, D]], np.uint8)          # rows = v (v = 0 the top row)
CAM = Camera(64, 48, 79.0)
POSE = look_at_pose((0.0, 0.0, 3.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))


def floor_scene(albedo: int = 255, uv_scale: float = 1.0, wrap=(REPEAT, REPEAT), textured=(True, True)) -> Scene:
    """A 4 x 4 m floor quad at z = 0: uv (x + 2) / 4, (2 - y) / 4 (times ``uv_scale``)."""
    v = np.array([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]], float)
    t = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32) * uv_scale
    return Scene(name="floor", vertices=v, triangles=t, tri_class=np.full(2, 14), tri_instance=np.zeros(2),
                 tri_albedo=np.full((2, 3), albedo), tri_texture=np.full(2, Texture.PLAIN), tri_uv=uv[t],
                 tri_material=np.where(textured, 0, -1), textures=[TEX], texture_wrap=np.array([wrap]),
                 meta={"lighting": "baked"})


def pixel_of(point) -> tuple[int, int]:
    """(row, column) of the pixel whose centre sees the world point."""
    p_cam = np.linalg.inv(POSE) @ np.append(np.asarray(point, float), 1.0)
    uvw = CAM.intrinsics @ p_cam[:3]
    return int(round(uvw[1] / uvw[2])), int(round(uvw[0] / uvw[2]))


def test_texel_at_hand_computed_pixels():
    """World (1, 1) has uv (0.75, 0.25): texel (x 1, y 0) = B; (-1, -1): uv (0.25, 0.75) -> C;
    (1, -1): uv (0.75, 0.75) -> D; (-1, 1): uv (0.25, 0.25) -> A."""
    view = Renderer(floor_scene(), CAM).render(POSE)
    for point, colour in (((1, 1, 0), B), ((-1, -1, 0), C), ((1, -1, 0), D), ((-1, 1, 0), A)):
        np.testing.assert_array_equal(view.rgb[pixel_of(point)], colour, err_msg=str(point))


def test_albedo_tints_the_texel():
    view = Renderer(floor_scene(albedo=128), CAM).render(POSE)
    np.testing.assert_array_equal(view.rgb[pixel_of((1, 1, 0))], np.round(np.array(B) * 128 / 255))


@pytest.mark.parametrize("mode,expect", [(REPEAT, [1, 0, 0, 1]), (CLAMP_TO_EDGE, [0, 0, 1, 1]),
                                         (MIRRORED_REPEAT, [0, 0, 1, 0])])
def test_wrap_modes(mode, expect):
    """Texels of a 2-texel axis at coordinates -0.25, 0.1, 1.25, 1.75 (floor(c x 2) = -1, 0, 2, 3)."""
    assert wrap_texels(np.array([-0.25, 0.1, 1.25, 1.75]), 2, mode).tolist() == expect


def test_wrap_in_the_renderer():
    """uv scaled by 2: world (1.02, 1.02) has u = 1.51 -> floor(u x 2) = 3: column 1 under REPEAT
    and CLAMP (B), column 0 under MIRRORED_REPEAT (A); v = 0.49 -> row 0 under all three."""
    for wrap in ((REPEAT, REPEAT), (CLAMP_TO_EDGE, CLAMP_TO_EDGE), (MIRRORED_REPEAT, MIRRORED_REPEAT)):
        view = Renderer(floor_scene(uv_scale=2.0, wrap=wrap), CAM).render(POSE)
        col3 = {REPEAT: 1, CLAMP_TO_EDGE: 1, MIRRORED_REPEAT: 0}[wrap[0]]
        np.testing.assert_array_equal(view.rgb[pixel_of((1.02, 1.02, 0))], TEX[0, col3], err_msg=str(wrap))


def test_untextured_triangles_and_scenes_render_as_before():
    part = Renderer(floor_scene(textured=(True, False)), CAM).render(POSE)
    plain_scene = floor_scene()
    plain_scene.tri_uv, plain_scene.tri_material, plain_scene.textures = None, None, []
    plain_scene.texture_wrap = np.zeros((0, 2), np.int32)
    plain = Renderer(plain_scene, CAM).render(POSE)
    r, c = pixel_of((-1, 1, 0))                                   # on triangle 1 (untextured in `part`)
    np.testing.assert_array_equal(part.rgb[r, c], plain.rgb[r, c])
    np.testing.assert_array_equal(part.rgb[pixel_of((1, -1, 0))], D)
    room = box_room_scene()
    assert not room.textured and Renderer(room, CAM)._textures is None


def test_textured_scene_npz_round_trip(tmp_path):
    s = floor_scene(wrap=(CLAMP_TO_EDGE, MIRRORED_REPEAT))
    back = Scene.load(s.save(tmp_path / "t.npz"))
    np.testing.assert_array_equal(back.tri_uv, s.tri_uv)
    np.testing.assert_array_equal(back.tri_material, s.tri_material)
    np.testing.assert_array_equal(back.texture_wrap, s.texture_wrap)
    np.testing.assert_array_equal(back.textures[0], TEX)
    room = box_room_scene()
    with np.load(room.save(tmp_path / "room.npz")) as data:   # untextured: the arrays it always had
        assert sorted(data.files) == ["meta", "tri_albedo", "tri_class", "tri_instance", "tri_texture", "triangles",
                                      "vertices"]
    assert Scene.load(tmp_path / "room.npz").tri_uv is None


def test_texture_arrays_are_checked():
    with pytest.raises(SceneError, match=r"tri_material must be in \[-1, 1\)"):
        s = floor_scene()
        Scene(**{**s.__dict__, "tri_material": np.array([0, 3])})
    with pytest.raises(SceneError, match="tri_uv and tri_material come together"):
        Scene(**{**floor_scene().__dict__, "tri_uv": None})
