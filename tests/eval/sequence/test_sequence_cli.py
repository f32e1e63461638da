"""`calnav export-sequence` / `calnav map` / `calnav calibrate-map --sequences` end to end on
tiny generated recordings, the export round trip, bad input, and the bench section."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from calnav.eval.cli import main
from tests.conftest import small_or_full
from tests.sequence_data import CLASSES, write_scannet

ROUND_TRIP = ["--frames", "8", "--resolution", "64x48", "--max-edge", "0.1"]


def _npz(path):
    from calnav.common.npz import load_versioned_npz
    from calnav.eval.sequence.map_cmd import MAP_FORMAT_VERSION

    return load_versioned_npz(path, MAP_FORMAT_VERSION)


def test_export_round_trip_matches_mapping_the_frames_in_memory(tmp_path):
    """Exported frames read back through the ScanNet reader give the same fused map and metrics
    as the rendered frames fused in memory (gt logits from the semantic frames, which do not
    depend on the lossy JPEG colour; millimetre depth on both sides)."""
    from calnav.agent.segmenters import make_segmenter
    from calnav.eval.calibration.record import HouseScan, scene_seed
    from calnav.eval.config import CALIBRATION_SECTIONS, load_config
    from calnav.eval.sequence.export import densify, depth_to_mm
    from calnav.eval.sequence.map_cmd import score
    from calnav.mapping.config import MappingConfig
    from calnav.mapping.ground_truth import nearest_vertex_labels
    from calnav.mapping.sequences import SequenceConfig, depth_from_raw
    from calnav.mapping.voxel_map import SemanticVoxelMap

    exp, out = tmp_path / "exp", tmp_path / "map"
    assert main(["export-sequence", *ROUND_TRIP, "--output", str(exp)]) == 0
    assert main(["map", str(exp), "--layout", "scannet", "--segmenter", "gt", "--output", str(out)]) == 0
    arrays, meta = _npz(out / "map.npz")
    results = json.loads((out / "results.json").read_text())
    assert meta["frames"] == 8 and results["frames"] == 8 and results["skipped_frames"] == []

    scene_id = "house_val_0000"
    cfg = load_config("configs/calibrate_map.yaml", ["env.resolution=64x48", "scan.frames=8"],
                      sections=CALIBRATION_SECTIONS)
    src = HouseScan(cfg, scene_id, scene_seed(scene_id, cfg.run.seed))
    seg = make_segmenter("gt")
    vmap = SemanticVoxelMap(len(CLASSES), MappingConfig(), class_names=CLASSES)
    for rgb, depth, sem, poses in src.batches(4):
        for i in range(len(rgb)):
            d = depth_from_raw(depth_to_mm(depth[i]), SequenceConfig())
            vmap.integrate(d, src.intrinsics, poses[i], seg.segment(rgb[i], d, semantic=sem[i]), rgb[i])
    coords, probs = vmap.voxels()
    np.testing.assert_array_equal(arrays["centres"], coords)
    np.testing.assert_allclose(arrays["probs"], probs, atol=1e-6)
    sc = src.scene
    v, _, vc = densify(sc.vertices, sc.triangles, sc.tri_class, 0.1)
    stats = score(probs, nearest_vertex_labels(coords, v.astype(np.float32), vc, SequenceConfig().label_distance_m),
                  len(CLASSES))
    for key in ("miou", "ece", "tl_ece", "mece", "brier"):
        assert results[key] == pytest.approx(getattr(stats, key)(), abs=1e-6), key
    assert 0.5 < results["miou"] <= 1.0 and results["labelled_voxels"] > 0.9 * results["voxels"]
    assert (out / "map.ply").exists() and (out / "reliability.png").exists()


def test_precomputed_logits_give_the_segmenters_map(tmp_path):
    from calnav.agent.segmenters import make_segmenter
    from calnav.mapping.sequences import Sequence

    root = write_scannet(tmp_path / "seq", n=4, bad_pose=1)
    seg = make_segmenter("gt")
    logits = tmp_path / "logits"
    logits.mkdir()
    (logits / "classes.json").write_text(json.dumps(list(CLASSES)))
    for f in Sequence(root, "scannet").frames():
        np.save(logits / f"{f.index}.npy", seg.segment(f.rgb, f.depth, semantic=f.semantic))
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["map", str(root), "--layout", "scannet", "--segmenter", "gt", "--output", str(a)]) == 0
    assert main(["map", str(root), "--layout", "scannet", "--logits", str(logits), "--output", str(b),
                 "mapping.fusion=glfs"]) == 0
    assert main(["map", str(root), "--layout", "scannet", "--logits", str(logits), "--output", str(a / "avg")]) == 0
    (x, _), (y, _) = _npz(a / "map.npz"), _npz(a / "avg" / "map.npz")
    np.testing.assert_array_equal(x["centres"], y["centres"])
    np.testing.assert_allclose(x["probs"], y["probs"], atol=1e-6)
    res = json.loads((b / "results.json").read_text())
    assert res["fusion"] == "glfs" and res["skipped_frames"] == [1] and res["frames"] == 3


def test_map_owns_its_results_directory(tmp_path, capsys):
    """A rerun with another config leaves no earlier map beside the new config.yaml."""
    root = write_scannet(tmp_path / "seq", n=3)
    out = tmp_path / "out"
    base = ["map", str(root), "--layout", "scannet", "--segmenter", "gt", "--output", str(out)]
    assert main(base) == 0
    (out / "reliability_classes.png").write_text("stale")
    assert main([*base, "mapping.fusion=rbu"]) == 2
    assert "holds results of a different config" in capsys.readouterr().err
    assert json.loads((out / "results.json").read_text())["fusion"] != "rbu"   # untouched
    assert main([*base, "--force", "mapping.fusion=rbu"]) == 0
    assert json.loads((out / "results.json").read_text())["fusion"] == "rbu"
    stale = out / "reliability_classes.png"
    assert not stale.exists() or stale.read_bytes()[:4] == b"\x89PNG"   # never the earlier run's file


def _fails(args, capsys, message: str, out) -> None:
    assert main([*args, "--output", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err
    assert not out.exists(), "nothing may be written on bad input"


def test_bad_input_is_one_line_before_anything_is_written(tmp_path, capsys):
    root = write_scannet(tmp_path / "seq", n=2)
    out = tmp_path / "out"
    (tmp_path / "empty").mkdir()
    _fails(["map", str(tmp_path / "empty"), "--layout", "scannet", "--segmenter", "gt"], capsys,
           "matches no scannet layout: expected color/N.jpg, depth/N.png, pose/N.txt", out)
    _fails(["map", str(root), "--layout", "scannet"], capsys, "exactly one of --segmenter NAME and --logits DIR", out)
    logits = tmp_path / "logits"
    logits.mkdir()
    (logits / "classes.txt").write_text("\n".join(CLASSES))
    np.save(logits / "0.npy", np.zeros((30, 40, 5), np.float32))
    _fails(["map", str(root), "--layout", "scannet", "--logits", str(logits)], capsys, "K = 5 classes", out)
    np.save(logits / "0.npy", np.zeros((31, 40, len(CLASSES)), np.float32))
    _fails(["map", str(root), "--layout", "scannet", "--logits", str(logits)], capsys, "are 40x31 pixels", out)
    ply = tmp_path / "plain.ply"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                   "property float z\nend_header\n0 0 0\n")
    _fails(["map", str(root), "--layout", "scannet", "--segmenter", "gt", "--labels-ply", str(ply)], capsys,
           "no vertex property 'label'", out)
    _fails(["map", str(root), "--layout", "scannet", "--segmenter", "gt", "mapping.fusion=nope"], capsys,
           "valid choices", out)
    (root / "intrinsic" / "intrinsic_color.txt").unlink()
    _fails(["map", str(root), "--layout", "scannet", "--segmenter", "gt"], capsys, "missing intrinsics", out)
    _fails(["export-sequence", "--scene", "house_nope_0000"], capsys, "unknown", out)


def test_calibrate_map_runs_on_recorded_sequences(tmp_path):
    for i, role in enumerate(("calib_train", "calib_val", "test")):
        write_scannet(tmp_path / f"scene000{i}_00", n=4)
    lst = tmp_path / "list.txt"
    lst.write_text("# role  directory  [layout]\ncalib_train scene0000_00\ncalib_val scene0001_00 scannet\n"
                   "test scene0002_00\n")
    out = tmp_path / "cal"
    assert main(["calibrate-map", "--quick", "--sequences", str(lst), "--output", str(out), "study.segmenters=[gt]",
                 "study.strategies=[rbu,averaging,glfs]", "study.calibrations=[none,temperature_2d,temperature_3d]",
                 small_or_full("run.workers=1", "run.workers=0")]) == 0   # small: no process pool to start
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert {(r["strategy"], r["calibration"]) for r in rows} >= {("rbu", "none"), ("rbu", "temperature_3d"),
                                                                  ("glfs", "learned")}
    assert all(float(r["miou"]) > 0.5 and int(r["n_voxels"]) > 0 for r in rows)
    assert (out / "scenes" / "gt" / "scene0002_00.cache.npz").exists()
    bad = tmp_path / "bad.txt"
    bad.write_text("train scene0000_00\n")
    assert main(["calibrate-map", "--sequences", str(bad), "--output", str(tmp_path / "cal2")]) == 2


def test_bench_sequence_section_figures(tmp_path):
    from calnav.eval.bench.sequence import measure

    root = write_scannet(tmp_path / "seq", n=4)
    out = measure(root, "40x30")
    for key in ("decode_ms_40x30", "segment_ms_40x30", "fusion_ms_40x30", "read_map_ms_40x30", "read_map_fps_40x30"):
        assert out[f"sequence.{key}"] > 0
    assert out["sequence.read_map_vs_parts"] > 0


def _break(root, logits, defect: str) -> None:
    """One per-frame defect (the list below), in frame 2 of a 3-frame recording."""
    import cv2

    if defect == "truncated jpeg":
        data = (root / "color" / "2.jpg").read_bytes()
        (root / "color" / "2.jpg").write_bytes(data[:len(data) // 3])
    elif defect == "3-channel depth":
        d = cv2.imread(str(root / "depth" / "2.png"), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(root / "depth" / "2.png"), np.dstack([d, d, d]))
    elif defect == "wrong-size depth":
        d = cv2.imread(str(root / "depth" / "2.png"), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(root / "depth" / "2.png"), d[:-2])
    elif defect == "missing semantic frame":
        (root / "semantic" / "2.png").unlink()
    elif defect == "nan logits":
        arr = np.load(logits / "2.npy")
        arr[0, 0, 0] = np.nan
        np.save(logits / "2.npy", arr)
    elif defect == "int8 logits":
        np.save(logits / "2.npy", np.load(logits / "2.npy").astype(np.int8))
    elif defect == "missing logits":
        (logits / "2.npy").unlink()
    elif defect == "truncated npy":
        data = (logits / "2.npy").read_bytes()
        (logits / "2.npy").write_bytes(data[:len(data) // 2])
    elif defect == "missing depth frame":
        (root / "depth" / "2.png").unlink()
    elif defect == "intrinsics of 4x the size":   # a 160x120 calibration on 40x30 images
        for name in ("intrinsic_color.txt", "intrinsic_depth.txt"):
            k = np.loadtxt(root / "intrinsic" / name)
            k[:2] *= 4   # fx, fy, cx, cy (rows 0, 1 of the 4x4 form)
            np.savetxt(root / "intrinsic" / name, k)
    elif defect == "depth at 5000 per metre":      # TUM's depth read with ScanNet's scale
        for f in (root / "depth").glob("*.png"):
            d = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
            cv2.imwrite(str(f), (d.astype(np.uint32) * 5).clip(0, 65534).astype(np.uint16))
    elif defect == "utm poses":                    # a GNSS map frame: 4,000 km north
        for f in (root / "pose").glob("*.txt"):
            pose = np.loadtxt(f)
            pose[:3, 3] += (5e5, 4e6, 0.0)
            np.savetxt(f, pose)
    elif defect == "nan ply vertex":
        from plyfile import PlyData

        ply_path = next(root.glob("*.labels.ply"))
        ply = PlyData.read(str(ply_path), mmap=False)
        ply["vertex"].data["x"][0] = np.nan
        ply.write(str(ply_path))


@pytest.mark.parametrize("defect, message", [
    ("truncated jpeg", "2.jpg"), ("3-channel depth", "frame 2: depth"), ("wrong-size depth", "depth/2.png is 40x28"),
    ("missing semantic frame", "have no semantic/ file, e.g. frame 2"), ("nan logits", "of frame 2 hold NaN"),
    ("int8 logits", "2.npy must be (H, W, K) float16 / float32, got int8"), ("missing logits", "no logits for frame 2"),
    ("truncated npy", "cannot read logits"), ("nan ply vertex", "1 vertices have NaN or inf coordinates"),
    # what real recordings get wrong with no other sign: each refused when the sequence opens
    ("missing depth frame", "1 colour / pose frames have no depth/N.png file, e.g. frame 2"),
    ("intrinsics of 4x the size", "the colour intrinsics for its 40x30 colour images: intrinsics put the principal point"),
    ("depth at 5000 per metre", "of the valid depth of frames [0, 1, 2] lies within mapping.depth_min_m-depth_max_m"),
    ("utm poses", "m from the origin, where the map's float32 coordinates are"),
])
def test_map_per_frame_defects_are_named_and_nothing_is_written(tmp_path, capsys, defect, message):
    """Per-frame problems are one line naming the frame, found before map.npz is written (no tracebacks)."""
    from calnav.agent.segmenters import make_segmenter
    from calnav.mapping.sequences import Sequence

    root = write_scannet(tmp_path / "seq", n=3)
    logits = tmp_path / "logits"
    logits.mkdir()
    (logits / "classes.json").write_text(json.dumps(list(CLASSES)))
    seg = make_segmenter("gt")
    for f in Sequence(root, "scannet").frames():
        np.save(logits / f"{f.index}.npy", seg.segment(f.rgb, f.depth, semantic=f.semantic))
    _break(root, logits, defect)
    out = tmp_path / "out"
    assert main(["map", str(root), "--layout", "scannet", "--logits", str(logits), "--output", str(out)]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]   # after the progress bar: one error line
    assert last.startswith("calnav map: error: ") and message in last, last
    assert not out.exists(), "nothing may be written on bad input"


def test_raw_dataset_ids_in_semantic_frames_are_refused(tmp_path, capsys):
    """semantic/N.png holds class index + 1; raw dataset ids there (99 for 18 classes) would
    make every such pixel void and the gt segmenter's map silently poorer."""
    import cv2

    root = write_scannet(tmp_path / "seq", n=3)
    sem = cv2.imread(str(root / "semantic" / "1.png"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(root / "semantic" / "1.png"), np.full_like(sem, 99))
    out = tmp_path / "out"
    assert main(["map", str(root), "--layout", "scannet", "--segmenter", "gt", "--output", str(out)]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert "frame 1: its semantic frame holds class id 98, past the 18 classes" in last, last
    assert not out.exists()


def test_a_map_with_no_voxels_or_nothing_to_score_is_an_error(tmp_path, capsys):
    """A depth range that holds none of the room fuses no voxel, and a labelled mesh elsewhere
    labels none: either map's metrics would be NaN (written as bare NaN, exit 0), so the command
    fails with a one-line error after the fusion (its progress bar before it) and writes
    nothing; a map that scores writes strict JSON."""
    from calnav.eval.sequence.export import densify, write_labels_ply
    from tests.sequence_data import room_mesh

    root = write_scannet(tmp_path / "seq", n=3)
    base = ["map", str(root), "--layout", "scannet", "--segmenter", "gt"]
    v, t, c = room_mesh()
    far = write_labels_ply(tmp_path / "far.ply", *densify(v + 100.0, t, c, 0.1))
    for extra, message, out in (
            # a depth range that misses the recording is refused when it opens, before fusing
            (["mapping.depth_max_m=0.2"], f"calnav map: error: {root}: only 0.0% of the valid depth of frames "
             "[0, 1, 2] lies within mapping.depth_min_m-depth_max_m (0.1-0.2 m; median", tmp_path / "near"),
            (["--labels-ply", str(far)], "calnav map: error: seq: none of the map's ",
             tmp_path / "far")):
        assert main([*base, *extra, "--output", str(out)]) == 2
        last = capsys.readouterr().err.rstrip("\n").split("\n")[-1]
        assert last.startswith(message), last
        assert not out.exists()
    assert f"lies within sequence.label_distance_m (0.05 m) of a labelled vertex of {far}: there is nothing" in last
    # a map that still holds no voxel after fusing (a recording of nothing in range) is refused too
    from types import SimpleNamespace

    from calnav.eval.config import load_config
    from calnav.eval.sequence.map_cmd import MappedSequence, check_map

    with pytest.raises(ValueError, match="seq: the map holds no voxels after fusing 3 frames .mapping.voxel_size_m "
                                         "0.05 m, depth 0.1-5 m.: no surface was reconstructed, nothing is written"):
        check_map(SimpleNamespace(name="seq"), MappedSequence(None, 3), load_config(None, []), np.zeros((0, 3)),
                  None, None)
    out = tmp_path / "ok"
    assert main([*base, "--output", str(out)]) == 0
    results = json.loads((out / "results.json").read_text(), parse_constant=lambda c: pytest.fail(f"bare {c}"))
    assert results["labelled_voxels"] > 0 and 0 <= results["miou"] <= 1
    # which table read the mesh's raw labels: the export's own label_map.json (not NYU40's ids)
    assert results["label_map"] == str(root / "label_map.json")
    assert f"ground truth through label map {root / 'label_map.json'})" in capsys.readouterr().out
