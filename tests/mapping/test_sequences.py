"""Recorded sequences (mapping/sequences/, eval/sequence/): near-rigid poses, colour-to-depth
registration, the ScanNet and 7-Scenes readers, vertex ground truth, mesh densification."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from calnav.mapping import frame_geometry as fg
from calnav.mapping.sequences import (LogitsDir, Registration, Sequence, SequenceConfig, depth_from_raw,
                               vertex_ground_truth)
from tests.sequence_data import CLASSES, FLOOR, TABLE, WALL, intrinsics, render_frames, write_scannet


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


# ------------------------------------------------------------------ poses
def test_check_pose_reorthonormalises_a_near_rigid_pose_hand_case():
    p = np.eye(4)
    p[:3, :3] = np.diag([1.001, 1.0, 1.0])   # |R^T R - I| = 2e-3: near rigid; nearest rotation = I
    p[:3, 3] = (1, 2, 3)
    out = fg.check_pose(p)
    np.testing.assert_allclose(out[:3, :3], np.eye(3), atol=1e-15)
    np.testing.assert_array_equal(out[:3, 3], (1, 2, 3))


def test_check_pose_accepts_7scenes_like_poses():
    """KinectFusion output: every rotation scaled by ~0.999925 (|R^T R - I| = 1.5e-4, det 0.9998)."""
    r = _rot_z(0.7) * 0.999925
    p = np.eye(4)
    p[:3, :3] = r
    assert abs(np.abs(r.T @ r - np.eye(3)).max() - 1.5e-4) < 1e-6
    out = fg.check_pose(p)
    np.testing.assert_allclose(out[:3, :3], _rot_z(0.7), atol=1e-12)
    assert abs(np.linalg.det(out[:3, :3]) - 1) < 1e-12
    exact = np.eye(4)
    exact[:3, :3] = _rot_z(0.7)
    np.testing.assert_array_equal(fg.check_pose(exact), exact)  # rigid to round-off: used unchanged


@pytest.mark.parametrize("scale, message", [(1.1, "not orthonormal"), (1.02, "not orthonormal")])
def test_check_pose_rejects_clearly_non_rigid(scale, message):
    p = np.eye(4)
    p[:3, :3] = _rot_z(0.3) * scale
    with pytest.raises(ValueError, match=message):
        fg.check_pose(p)


def test_check_pose_rejects_a_reflection():
    p = np.diag([1.0, 1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="det"):
        fg.check_pose(p)


def test_integrate_accepts_a_near_rigid_pose():
    from calnav.mapping.config import MappingConfig
    from calnav.mapping.voxel_map import SemanticVoxelMap

    frames, k = render_frames(1)
    rgb, depth, labels, pose = frames[0]
    pose = pose.copy()
    pose[:3, :3] *= 0.999925
    vmap = SemanticVoxelMap(len(CLASSES), MappingConfig())
    vmap.integrate(depth, k, pose, np.zeros((*depth.shape, len(CLASSES)), np.float32))
    assert len(vmap.voxels()[0]) > 0


# ------------------------------------------------------------ registration
def test_registration_hand_case():
    """Depth camera 5x3, colour camera 10x6 at twice the focal length; principal points that
    do *not* scale: colour pixel = (2u + 1, 2v) -- (2u + 2, 2v) falls off the right edge at u = 4."""
    kd = np.array([[10.0, 0, 2], [0, 10, 1], [0, 0, 1]])
    colour = np.arange(60).reshape(6, 10)
    rgb = np.repeat(colour[:, :, None], 3, axis=2).astype(np.uint8)
    kc = np.array([[20.0, 0, 5], [0, 20, 2], [0, 0, 1]])
    reg = Registration(kc, (10, 6), kd, (5, 3))
    v, u = np.mgrid[0:3, 0:5]
    np.testing.assert_array_equal(reg.labels(colour), colour[2 * v, 2 * u + 1])
    np.testing.assert_array_equal(reg.rgb(rgb)[..., 0], colour[2 * v, 2 * u + 1])
    kc[0, 2] = 6
    reg = Registration(kc, (10, 6), kd, (5, 3))
    expect = np.where(u < 4, colour[2 * v, np.minimum(2 * u + 2, 9)], -1)
    np.testing.assert_array_equal(reg.labels(colour), expect)
    logits = np.stack([colour, -colour], axis=2).astype(np.float32)
    out = reg.logits(logits)
    np.testing.assert_array_equal(out[..., 0], np.where(u < 4, expect, 0))
    assert (out[:, 4] == 0).all()   # off the colour image: uniform
    same = Registration(kd, (5, 3), kd, (5, 3))
    assert same.identity and same.rgb(rgb) is rgb


# ----------------------------------------------------------------- readers
def test_scannet_reader_reads_back_what_was_written_and_skips_invalid_poses(tmp_path):
    from calnav.eval.sequence.export import depth_to_mm

    root = write_scannet(tmp_path / "seq", n=4, bad_pose=2)
    frames, k = render_frames(4)
    seq = Sequence(root, "scannet")
    assert seq.skipped == [2] and seq.ids == [0, 1, 3] and len(seq) == 3
    got = list(seq.frames())
    assert [f.index for f in got] == [0, 1, 3]
    for f in got:
        rgb, depth, labels, pose = frames[f.index]
        np.testing.assert_array_equal(f.pose, pose)          # 17 digits: bit-exact
        np.testing.assert_array_equal(f.depth, depth_from_raw(depth_to_mm(depth), SequenceConfig()))
        assert np.abs(f.depth - depth).max() <= 0.0005 + 1e-6   # millimetre rounding
        np.testing.assert_array_equal(f.semantic, labels)
        np.testing.assert_array_equal(f.k_depth, k)
        assert np.abs(f.rgb.astype(int) - rgb).mean() < 10     # JPEG: lossy but the same image
    cfg = SequenceConfig(frame_stride=2, max_frames=1, depth_trunc_m=1.5)
    seq = Sequence(root, "scannet", cfg)
    (only,) = list(seq.frames())
    assert only.index == 0 and only.depth.max() <= 1.5 and (only.depth == 0).any()


def test_7scenes_reader_masks_invalid_depth_and_accepts_kinectfusion_poses(tmp_path):
    frames, k = render_frames(3)
    seq_dir = tmp_path / "chess" / "seq-01"
    seq_dir.mkdir(parents=True)
    np.savetxt(tmp_path / "chess" / "camera-intrinsics.txt", k)   # 3DMatch: in the scene folder
    for i, (rgb, depth, labels, pose) in enumerate(frames):
        raw = np.rint(depth * 1000).astype(np.uint16)
        raw[0, :5] = 65535
        cv2.imwrite(str(seq_dir / f"frame-{i:06d}.color.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(seq_dir / f"frame-{i:06d}.depth.png"), raw)
        p = pose.copy()
        p[:3, :3] *= 0.999925
        np.savetxt(seq_dir / f"frame-{i:06d}.pose.txt", p, fmt="%.8e")
    seq = Sequence(seq_dir, "7scenes")
    got = list(seq.frames())
    assert len(got) == 3 and not seq.skipped
    for f in got:
        rgb, depth, _, pose = frames[f.index]
        assert (f.depth[0, :5] == 0).all()
        np.testing.assert_allclose(f.depth[1:], depth[1:], atol=0.0005 + 1e-6)
        np.testing.assert_array_equal(f.rgb, rgb)               # PNG: lossless
        np.testing.assert_allclose(f.pose, pose, atol=1e-7)     # re-orthonormalised
        assert f.semantic is None
    # a lost depth frame: its colour and pose are there, the frame would be dropped unsaid
    (seq_dir / "frame-000001.depth.png").unlink()
    with pytest.raises(ValueError, match="1 colour / pose frames have no depth file, e.g. frame 1"):
        Sequence(seq_dir, "7scenes")


@pytest.mark.parametrize("k, ok", [
    ([[100, 0, 79.5, 0], [0, 100, 59.5, 0]], True),     # centred on a 160x120 image
    ([[100, 0, 100.0, 0], [0, 100, 59.5, 0]], True),    # 12.5% right of the centre (a crop): accepted
    ([[100, 0, 112.0, 0], [0, 100, 59.5, 0]], True),    # exactly 20%: the bound itself
    ([[100, 0, 113.0, 0], [0, 100, 59.5, 0]], False),   # 20.6%: past MAX_PRINCIPAL_OFFSET
    ([[400, 0, 319.5, 0], [0, 400, 239.5, 0]], False),  # a 640x480 calibration
    ([[25, 0, 39.5, 0], [0, 25, 29.5, 0]], False),      # an 80x60 one
])
def test_the_principal_point_must_fit_the_image(k, ok):
    """|cx - W/2| / W and |cy - H/2| / H at most 0.2 for a W x H = 160 x 120 image: (100 - 80) /
    160 = 0.125 and (112 - 80) / 160 = 0.2 pass, (113 - 80) / 160 = 0.206 does not."""
    from calnav.mapping.frame_geometry import check_intrinsics

    m = np.array([*k, [0, 0, 1, 0]], float)[:, :3]
    if ok:
        np.testing.assert_array_equal(check_intrinsics(m, 160, 120), m)
    else:
        with pytest.raises(ValueError, match=r"image's size off the centre of a 160x120 image \(at most 20%\)"):
            check_intrinsics(m, 160, 120)


def test_readers_name_what_is_missing(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="matches no scannet layout: expected color/N.jpg"):
        Sequence(tmp_path / "empty", "scannet")
    with pytest.raises(ValueError, match="matches no 7scenes layout: expected frame-NNNNNN"):
        Sequence(tmp_path / "empty", "7scenes")
    root = write_scannet(tmp_path / "seq", n=2)
    with pytest.raises(ValueError, match="pass --layout scannet"):
        Sequence(root, "7scenes")
    (root / "intrinsic" / "intrinsic_depth.txt").unlink()
    with pytest.raises(ValueError, match="missing intrinsics: .*intrinsic_depth.txt"):
        Sequence(root, "scannet")


def test_layouts_are_chosen_from_their_registry(tmp_path):
    """Every ``LAYOUTS`` name loads its opener from the readers, and an unknown layout is one
    line naming the valid choices (before the directory is looked at)."""
    from calnav.mapping.sequences import LAYOUTS, readers

    assert LAYOUTS.get("scannet") is readers.open_scannet and LAYOUTS.get("7scenes") is readers.open_7scenes
    assert all(callable(LAYOUTS.get(name)) for name in LAYOUTS)
    with pytest.raises(ValueError, match=f"^unknown sequence layout 'scanet'; valid choices: {', '.join(LAYOUTS)}$"):
        Sequence(tmp_path / "nowhere", "scanet")


def test_non_rigid_pose_is_rejected_with_its_frame_number(tmp_path):
    root = write_scannet(tmp_path / "seq", n=3)
    p = np.loadtxt(root / "pose" / "1.txt")
    p[:3, :3] *= 1.05
    np.savetxt(root / "pose" / "1.txt", p)
    with pytest.raises(ValueError, match=r"frame 1 .*not orthonormal"):
        Sequence(root, "scannet")


def test_an_8bit_depth_frame_is_refused_with_its_frame_number(tmp_path):
    """An 8-bit depth PNG after the first frame is refused, naming the frame (not read as millimetres, 0-25 cm)."""
    root = write_scannet(tmp_path / "seq", n=3)
    depth = cv2.imread(str(root / "depth" / "2.png"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(root / "depth" / "2.png"), (depth // 256).astype(np.uint8))
    seq = Sequence(root, "scannet")
    seq.read(0)
    with pytest.raises(ValueError, match=r"frame 2: depth .*2.png must be a single-channel 16-bit PNG, got uint8"):
        seq.read(2)


def test_class_list_with_a_repeated_name_is_refused(tmp_path):
    """A classes.json naming a class twice is refused (it would give mIoU 0.748 instead of 0.957 with exit 0)."""
    from calnav.mapping.sequences.labels import read_class_list

    path = tmp_path / "classes.json"
    path.write_text(json.dumps(["wall", "floor", "chair", "floor"]))
    with pytest.raises(ValueError, match="names 'floor' twice"):
        read_class_list(path)
    path.write_text("[wall, floor")
    with pytest.raises(ValueError, match="is not valid JSON"):
        read_class_list(path)


def test_logits_dir_checks_class_count_and_size(tmp_path):
    root = write_scannet(tmp_path / "seq", n=2)
    seq = Sequence(root, "scannet")
    d = tmp_path / "logits"
    d.mkdir()
    (d / "classes.txt").write_text("\n".join(CLASSES))
    np.save(d / "0.npy", np.zeros((30, 40, len(CLASSES)), np.float16))
    np.savez(d / "1.npz", logits=np.zeros((30, 40, len(CLASSES)), np.float32))
    src = LogitsDir(d, seq)
    assert src.get(1).dtype == np.float32 and src.get(0).shape == (30, 40, len(CLASSES))
    np.save(d / "0.npy", np.zeros((30, 40, 3), np.float32))
    with pytest.raises(ValueError, match="K = 3 classes, the class list names 18"):
        LogitsDir(d, seq)
    np.save(d / "0.npy", np.zeros((20, 40, len(CLASSES)), np.float32))
    with pytest.raises(ValueError, match="are 40x20 pixels; expected 40x30"):
        LogitsDir(d, seq)


# ------------------------------------------------------------ ground truth
def test_nearest_vertex_labels_hand_case():
    from calnav.mapping.ground_truth import nearest_vertex_labels

    verts = np.array([[0, 0, 0], [1, 0, 0], [0.5, 0, 0]], float)
    labels = np.array([3, 5, -1])                 # the middle vertex is unannotated
    pts = np.array([[0.1, 0, 0], [0.9, 0.05, 0], [0.5, 0, 0], [3, 0, 0]], float)
    np.testing.assert_array_equal(nearest_vertex_labels(pts, verts, labels, 0.2), [3, 5, -1, -1])
    np.testing.assert_array_equal(nearest_vertex_labels(pts, verts, labels, 0.6), [3, 5, 3, -1])


def _ply(path, labels, prop="label"):
    from plyfile import PlyData, PlyElement

    v = np.zeros(len(labels), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), (prop, "u2")])
    v["x"] = np.arange(len(labels))
    v[prop] = labels
    PlyData([PlyElement.describe(v, "vertex")]).write(str(path))
    return path


def test_vertex_ground_truth_label_maps(tmp_path):
    """NYU40 ids (ScanNet's default) map to calnav's classes by name or synonym, and to
    ScanNet-20 names exactly; a label_map.json in the sequence folder wins."""
    ply = _ply(tmp_path / "s_vh_clean_2.labels.ply", [1, 2, 7, 10, 25, 0, 40])
    _, cls = vertex_ground_truth(ply, CLASSES, SequenceConfig())
    shelf, tv = CLASSES.index("shelf"), CLASSES.index("tv_monitor")
    np.testing.assert_array_equal(cls, [WALL, FLOOR, TABLE, shelf, tv, -1, -1])
    scannet20 = ("wall", "floor", "cabinet", "bed", "chair", "sofa", "table", "door", "window", "bookshelf")
    _, cls = vertex_ground_truth(ply, scannet20, SequenceConfig())
    np.testing.assert_array_equal(cls, [0, 1, 6, 9, -1, -1, -1])
    (tmp_path / "label_map.json").write_text(json.dumps({"1": "table", "2": "floor"}))
    _, cls = vertex_ground_truth(ply, CLASSES, SequenceConfig(), tmp_path)
    np.testing.assert_array_equal(cls, [TABLE, FLOOR] + [-1] * 5)
    with pytest.raises(ValueError, match="none of its labels"):
        vertex_ground_truth(ply, ("foo", "bar"), SequenceConfig())
    with pytest.raises(ValueError, match="no vertex property 'label'"):
        vertex_ground_truth(_ply(tmp_path / "x.ply", [1, 2], prop="nyu"), CLASSES, SequenceConfig())


def test_the_label_map_beside_the_ply_or_in_the_sequence_is_used_unless_configured(tmp_path):
    """No sequence.label_map: the label_map.json beside the mesh (a bag file's --labels-ply), or
    the sequence's own; the same table in both is one; two different ones are refused."""
    from calnav.mapping.sequences import label_map_source

    seq_dir, mesh_dir = tmp_path / "seq", tmp_path / "meshes"
    seq_dir.mkdir(), mesh_dir.mkdir()
    ply = _ply(mesh_dir / "s.labels.ply", [1, 2])
    assert label_map_source(SequenceConfig(), seq_dir, ply) == "nyu40"
    table = json.dumps({"1": "table", "2": "floor"})
    (mesh_dir / "label_map.json").write_text(table)
    assert label_map_source(SequenceConfig(), seq_dir, ply) == str(mesh_dir / "label_map.json")
    _, cls = vertex_ground_truth(ply, CLASSES, SequenceConfig(), tmp_path / "bag.db3")
    np.testing.assert_array_equal(cls, [TABLE, FLOOR])
    (seq_dir / "label_map.json").write_text(table)
    assert label_map_source(SequenceConfig(), seq_dir, ply) == str(mesh_dir / "label_map.json")
    (seq_dir / "label_map.json").write_text(json.dumps({"1": "wall"}))
    with pytest.raises(ValueError, match="two different label maps for .*s.labels.ply: .*meshes/label_map.json "
                                         "\\(beside it\\) and .*seq/label_map.json \\(in the sequence's directory\\)"):
        vertex_ground_truth(ply, CLASSES, SequenceConfig(), seq_dir)
    assert label_map_source(SequenceConfig(label_map="nyu40"), seq_dir, ply) == "nyu40"


def test_densify_bounds_edges_and_keeps_area_and_classes():
    from calnav.eval.sequence.export import densify

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]], float)
    t = np.array([[0, 1, 2], [1, 3, 2]])
    dv, dt, dc = densify(v, t, np.array([4, 7]), 0.1)
    e = np.linalg.norm(dv[dt] - dv[np.roll(dt, 1, axis=1)], axis=2)
    assert e.max() <= 0.1

    def area(verts, tris):
        a, b, c = (verts[tris[:, i]] for i in range(3))
        return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)

    np.testing.assert_allclose(area(dv, dt).sum(), area(v, t).sum(), rtol=1e-9)
    assert set(dc.tolist()) == {4, 7}
    on_first = np.abs(dv[:, 2]) < 1e-12
    assert (dc[on_first & (dv.sum(1) < 1 - 1e-9)] == 4).all()   # strictly inside triangle 0: its class


def test_prefetched_keeps_order_reraises_and_stops_its_thread():
    import threading

    from calnav.common.prefetch import prefetched

    assert list(prefetched(iter(range(7)))) == list(range(7))

    def failing():
        yield 1
        raise ValueError("frame 2: broken")

    got = []
    with pytest.raises(ValueError, match="frame 2: broken"):
        for x in prefetched(failing()):
            got.append(x)
    assert got == [1]
    before = threading.active_count()
    gen = prefetched(iter(range(1000)))
    assert next(gen) == 0
    gen.close()   # the consumer stops early: the producer thread must end, not block on the queue
    assert threading.active_count() <= before


def test_scannet_label_filt_frames_map_through_the_label_table(tmp_path):
    """ScanNet's label-filt/N.png hold raw ScanNet ids; with sequence.frame_label_map (e.g.
    scannetv2-labels.combined.tsv) and a class list they become per-frame class labels."""
    from calnav.mapping.sequences import read_scannet

    root = write_scannet(tmp_path / "seq", n=2)
    frames, _ = render_frames(2)
    raw_of = {WALL: 1, FLOOR: 2, TABLE: 7, -1: 0}   # ScanNet raw ids of the room's classes (0: unlabelled)
    for d in root.glob("semantic/*.png"):
        d.unlink()
    (root / "label-filt").mkdir()
    for i, (_, _, labels, _) in enumerate(frames):
        raw = np.vectorize(lambda c: raw_of.get(int(c), 0))(labels).astype(np.uint16)
        cv2.imwrite(str(root / "label-filt" / f"{i}.png"), raw)
    tsv = tmp_path / "scannetv2-labels.combined.tsv"
    tsv.write_text("id\traw_category\tcategory\tnyu40id\tnyu40class\n1\twall\twall\t1\twall\n"
                   "2\tfloor\tfloor\t2\tfloor\n7\tdining table\tdining table\t7\ttable\n")
    assert all(f.semantic is None for f in read_scannet(root))           # no table: not read
    seq = Sequence(root, "scannet", SequenceConfig(frame_label_map=str(tsv)))
    assert not seq.has_semantic
    seq.use_class_names(CLASSES)
    assert seq.has_semantic
    for f in seq.frames():
        labels = frames[f.index][2]
        expect = np.where(np.isin(labels, [WALL, FLOOR, TABLE]), labels, -1)   # the ceiling has no raw id here
        np.testing.assert_array_equal(f.semantic, expect)
    reg = Registration(intrinsics(80, 60), (80, 60), seq.k_depth, seq.depth_size)
    assert reg.labels(expect) is expect                                   # already at the depth size
    with pytest.raises(ValueError, match="label image is 3x3"):
        reg.labels(np.zeros((3, 3), np.int64))
