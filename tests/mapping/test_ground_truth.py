"""Ground truth from labelled meshes (mapping.ground_truth)."""
import numpy as np
import pytest

from calnav.envs.primitives import box_room_scene
from calnav.envs.semantics import CLASS_ID
from calnav.mapping.ground_truth import LabelledMesh, voxel_labels


@pytest.fixture(scope="module")
def room():
    return box_room_scene()


def test_voxel_labels_nearest_triangle_and_void(room):
    coords = np.array([
        [0.0, 0.0, 0.02],    # just above the floor
        [2.98, 0.0, 1.3],    # next to the +x wall
        [0.0, 0.0, 2.58],    # under the ceiling
        [1.5, 1.0, 0.91],    # on top of the chair (0.9 m high)
        [0.0, 0.5, 1.3],     # middle of the room: free space
    ], np.float32)
    labels = voxel_labels(coords, room.vertices, room.triangles, room.tri_class)
    assert labels.tolist() == [CLASS_ID["floor"], CLASS_ID["wall"], CLASS_ID["ceiling"], CLASS_ID["chair"], -1]
    far = voxel_labels(coords[4:], room.vertices, room.triangles, room.tri_class, max_dist_m=10.0)
    assert far[0] >= 0  # within a generous radius everything has a nearest surface
    assert voxel_labels(np.zeros((0, 3)), room.vertices, room.triangles, room.tri_class).shape == (0,)


def test_default_radius_is_one_voxel_diagonal(room):
    inside = np.array([[0.0, 0.0, 0.08]], np.float32)   # 8 cm above the floor < 8.66 cm
    outside = np.array([[0.0, 0.0, 0.09]], np.float32)
    assert voxel_labels(inside, room.vertices, room.triangles, room.tri_class)[0] == CLASS_ID["floor"]
    assert voxel_labels(outside, room.vertices, room.triangles, room.tri_class)[0] == -1
    assert voxel_labels(outside, room.vertices, room.triangles, room.tri_class, voxel_size_m=0.1)[0] == CLASS_ID["floor"]


def test_render_depth_and_labels(room):
    mesh = LabelledMesh(room.vertices, room.triangles, room.tri_class)
    w, h, f = 64, 48, 40.0
    k = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
    pose = np.eye(4)
    pose[:3, :3] = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]]).T  # camera x, y, z -> world -y, -z, +x
    pose[:3, 3] = (0.0, 0.0, 1.3)
    depth, labels = mesh.render(k, pose, w, h)
    assert depth.dtype == np.float32 and labels.shape == (h, w)
    # the central pixels see the +x wall at x = 3 (z-depth 3 m along the optical axis)
    assert depth[h // 2, w // 2] == pytest.approx(3.0, abs=1e-4)
    assert labels[h // 2, w // 2] == CLASS_ID["wall"]
    assert labels[-1, w // 2] == CLASS_ID["floor"] and labels[0, w // 2] == CLASS_ID["ceiling"]
    depth_clip, labels_clip = mesh.render(k, pose, w, h, depth_max_m=2.0)
    assert (depth_clip[labels_clip < 0] == 0).all() and depth_clip.max() <= 2.0


def test_bad_meshes():
    with pytest.raises(ValueError, match="triangles"):
        voxel_labels(np.zeros((1, 3)), np.zeros((3, 3)), np.zeros((0, 3), int), np.zeros(0))
    with pytest.raises(ValueError, match="tri_class"):
        voxel_labels(np.zeros((1, 3)), np.eye(3), np.array([[0, 1, 2]]), np.zeros(2))
    with pytest.raises(ValueError, match=r"\(V, 3\)"):
        voxel_labels(np.zeros((1, 3)), np.zeros((3, 2)), np.array([[0, 1, 2]]), np.zeros(1))
