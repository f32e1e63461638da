"""The segmenter's appearance levers: the camera-like training augmentation
(eval.segmenter.photometric), the recolouring of training instances and the camera-shifted
evaluation (eval.segmenter.appearance). Each changes the image when on and leaves it (and the
augmentation stream) bit-identical when off; ranges are refused in one line; the cache keys of
the default config are those of the releases before the levers."""
import dataclasses

import numpy as np
import pytest
import torch

from calnav.eval.config import SEGMENTER_SECTIONS, load_config
from calnav.eval.sections import SegDataConfig, TrainConfig
from calnav.eval.segmenter import photometric as P

LEVERS_ON = {"exposure_ev": 1.0, "white_balance": 0.3, "tint": 0.2, "gamma": 0.5, "vignette": 0.5,
             "motion_blur_prob": 1.0, "shot_noise": 20.0, "jpeg_prob": 1.0}


def _batch() -> torch.Tensor:
    return torch.rand(4, 3, 24, 32, generator=torch.Generator().manual_seed(3)) * 0.8 + 0.1


@pytest.mark.parametrize("key", sorted(LEVERS_ON))
def test_each_lever_changes_the_image_when_on(key):
    cfg = dataclasses.replace(TrainConfig(), **{key: LEVERS_ON[key]})
    rgb = _batch()
    gen = torch.Generator().manual_seed(0)
    out = P.jpeg_lever(P.camera_levers(rgb, gen, cfg), gen, cfg)
    assert out.shape == rgb.shape and float((out - rgb).abs().max()) > 0.01
    assert float(out.min()) >= 0.0 and float(out.max()) <= 1.0


def test_levers_off_are_bit_identical_and_draw_nothing():
    rgb = _batch()
    gen = torch.Generator().manual_seed(0)
    state = gen.get_state()
    cfg = TrainConfig()
    assert torch.equal(P.jpeg_lever(P.camera_levers(rgb, gen, cfg), gen, cfg), rgb)
    assert torch.equal(gen.get_state(), state)


def test_augment_at_defaults_keeps_its_stream():
    """augment() with the levers at 0 returns what the pre-lever augmentation drew (same
    generator state after it too)."""
    from calnav.eval.segmenter.train import augment

    labels = torch.zeros(4, 24, 32, dtype=torch.int64)
    off, on = TrainConfig(), dataclasses.replace(TrainConfig(), exposure_ev=1.0)
    g1, g2 = torch.Generator().manual_seed(5), torch.Generator().manual_seed(5)
    a, _, _ = augment(_batch(), None, labels, g1, off, 5.0)
    b, _, _ = augment(_batch(), None, labels, g2, dataclasses.replace(off, exposure_ev=0.0, jpeg_prob=0.0), 5.0)
    assert torch.equal(a, b) and torch.equal(g1.get_state(), g2.get_state())
    c, _, _ = augment(_batch(), None, labels, torch.Generator().manual_seed(5), on, 5.0)
    assert not torch.equal(a, c)


def test_exposure_and_tone_by_hand():
    rgb = torch.tensor([0.25, 0.5, 0.8]).view(1, 3, 1, 1)
    # +1 EV doubles (0.8 -> 1.6 clips at 1); -1 EV halves
    np.testing.assert_allclose(P.exposure(rgb, torch.tensor([1.0])).flatten().numpy(), [0.5, 1.0, 1.0])
    np.testing.assert_allclose(P.exposure(rgb, torch.tensor([-1.0])).flatten().numpy(), [0.125, 0.25, 0.4])
    # log2 gamma 1: exponent 2, 0.25 -> 0.0625; log2 gamma -1: square root, 0.25 -> 0.5
    np.testing.assert_allclose(P.tone(rgb, torch.tensor([1.0])).flatten().numpy(), [0.0625, 0.25, 0.64], rtol=1e-6)
    np.testing.assert_allclose(P.tone(rgb, torch.tensor([-1.0])).flatten().numpy(),
                               [0.5, 0.5 ** 0.5, 0.8 ** 0.5], rtol=1e-6)
    g = P.white_balance_gains(torch.tensor([0.1]), torch.tensor([0.0]))
    np.testing.assert_allclose(g.numpy(), [[np.exp(0.1), 1.0, np.exp(-0.1)]], rtol=1e-6)
    k = P.motion_blur_kernel(6.0, 0.0)   # horizontal streak: one row, summing to 1
    assert float(k.sum()) == pytest.approx(1.0) and float(k[k.shape[0] // 2].sum()) == pytest.approx(1.0)


@pytest.mark.parametrize("key,bad", [("exposure_ev", 3.5), ("exposure_ev", float("nan")), ("white_balance", -0.1),
                                     ("tint", 1.5), ("gamma", float("nan")), ("vignette", 0.95),
                                     ("motion_blur_prob", 1.2), ("motion_blur_px", 1.0), ("shot_noise", 41.0),
                                     ("jpeg_prob", float("nan"))])
def test_lever_ranges_are_refused(key, bad):
    with pytest.raises(ValueError, match=rf"^train\.{key} must be in \["):
        TrainConfig(**{key: bad})


@pytest.mark.parametrize("quality", [(90, 30), (2, 50), (50, 101), (float("nan"), 50)])
def test_jpeg_quality_range_is_refused(quality):
    with pytest.raises(ValueError, match=r"^train\.jpeg_quality must be \[lo, hi\] with 5 <= lo <= hi <= 100"):
        TrainConfig(jpeg_quality=quality)


def test_data_keys_are_refused():
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match=r"^data\.recolour_fraction must be in \[0, 1\]"):
            SegDataConfig(recolour_fraction=bad)
    with pytest.raises(ValueError, match="^unknown data.eval_appearance 'phone'; valid choices: none, camera, recolour$"):
        SegDataConfig(eval_appearance="phone")


def test_default_cache_keys_are_unchanged():
    """The default config's cache names: the clean evaluation set's is the one it had before the
    levers existed, the training set's (half its frames from scans) holds the scan versions
    (``envs.scenes.scan_versions``); recolouring changes the training key only, the eval shift no key."""
    from calnav.eval.segmenter.data import cache_path

    cfg = load_config("configs/segmenter.yaml", [], sections=SEGMENTER_SECTIONS)
    train = cache_path(cfg.env, cfg.data, "train", 20000, 0, False, True)
    test = cache_path(cfg.env, cfg.data, "test", 500, 1000, False, False)
    assert (train.name, test.name) == ("train_20000_fdbf02ae401a.npz", "test_500_40fbbe894513.npz")
    recol = dataclasses.replace(cfg.data, recolour_fraction=0.5)
    camera = dataclasses.replace(cfg.data, eval_appearance="camera")
    assert cache_path(cfg.env, recol, "train", 20000, 0, False, True) != train
    assert cache_path(cfg.env, recol, "test", 500, 1000, False, False) == test
    assert cache_path(cfg.env, camera, "test", 500, 1000, False, False) == test
    assert cache_path(cfg.env, cfg.data, "test", 500, 1000, False, False, recolour_all=True) != test


def test_recolour_scene_redraws_the_chosen_instances_only():
    from calnav.envs.config import DatasetConfig
    from calnav.envs.scenes import load_scene, split_scene_ids
    from calnav.eval.segmenter.appearance import recolour_scene

    dataset = DatasetConfig()
    scene = load_scene(split_scene_ids("train", dataset)[0], dataset)
    before = scene.tri_albedo.copy()
    same = recolour_scene(scene, 0.0, np.random.default_rng(0))
    assert np.array_equal(same.tri_albedo, before) and np.array_equal(same.tri_texture, scene.tri_texture)
    all_ = recolour_scene(scene, 1.0, np.random.default_rng(0))
    assert np.array_equal(scene.tri_albedo, before)   # the (cached) scene itself is untouched
    assert (all_.tri_albedo != before).any(axis=1).mean() > 0.9
    half = recolour_scene(scene, 0.5, np.random.default_rng(1))
    changed = np.unique(scene.tri_instance[(half.tri_albedo != before).any(axis=1)])
    n = len(np.unique(scene.tri_instance))
    assert 0.2 * n < len(changed) < 0.8 * n


def _quad_scene(name: str, albedo: np.ndarray, subdivide: int, meta: dict) -> "Scene":
    """Two unit squares side by side in z = 0 (instance 0: x in [0, 1], instance 1: x in [1, 2]),
    each cut into ``subdivide`` x ``subdivide`` cells of two triangles; ``albedo(x)`` colours a
    triangle by its centroid's x."""
    from calnav.envs.scene import Scene
    from calnav.envs.semantics import CLASS_NAMES

    n = 2 * subdivide
    xs, ys = np.meshgrid(np.linspace(0, 2, n + 1), np.linspace(0, 1, subdivide + 1))
    v = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    idx = lambda i, j: j * (n + 1) + i  # noqa: E731
    t = np.array([tri for j in range(subdivide) for i in range(n)
                  for tri in ((idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)), (idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)))])
    cx = v[t].mean(axis=1)[:, 0]
    return Scene(name=name, vertices=v, triangles=t, tri_class=np.full(len(t), CLASS_NAMES.index("chair")),
                 tri_instance=(cx > 1).astype(np.int32), tri_albedo=albedo(cx), tri_texture=np.zeros(len(t)), meta=meta)


def test_recolouring_a_scan_goes_by_the_clean_parts_and_keeps_its_shading():
    """A baked scan's triangles each have their own colour; recolouring gives every part of the
    clean house (instance and albedo) one new colour, times each triangle's own shading."""
    from calnav.eval.segmenter.appearance import LUMA, MIN_LUMA, recolour_scene

    part_colour = lambda cx: np.where((cx % 1 < 0.5)[:, None], [200, 60, 60], [60, 60, 200])  # noqa: E731
    clean = _quad_scene("clean", part_colour, 2, {})
    shading = np.random.default_rng(0).uniform(0.4, 1.0, 2 * 8 * 8 * 2)
    scan = _quad_scene("scan", lambda cx: np.round(part_colour(cx) * shading[:, None]), 8, {"lighting": "baked"})
    assert len(np.unique(scan.tri_albedo, axis=0)) > 50   # one colour per triangle, as a TSDF bakes them
    with pytest.raises(ValueError, match="needs the clean house it was scanned from"):
        recolour_scene(scan, 1.0, np.random.default_rng(0))
    with pytest.raises(ValueError, match="scans loaded from scene files have none"):
        recolour_scene(scan, 1.0, np.random.default_rng(0), source=scan)
    out = recolour_scene(scan, 1.0, np.random.default_rng(0), source=clean)
    assert np.array_equal(out.tri_texture, scan.tri_texture)   # the baked pattern stays
    cx = scan.vertices[scan.triangles].mean(axis=1)[:, 0]
    part = (cx > 1) * 2 + (cx % 1 >= 0.5)
    own = (scan.tri_albedo @ LUMA) / np.maximum(part_colour(cx) @ LUMA, MIN_LUMA)   # each triangle's shading
    base = out.tri_albedo / own[:, None]   # the part's new colour, up to rounding
    for p in range(4):
        spread = base[part == p].max(axis=0) - base[part == p].min(axis=0)
        assert spread.max() < 1.0 / own[part == p].min() + 1e-6, (p, spread)
    means = np.array([base[part == p].mean(axis=0) for p in range(4)])
    assert np.abs(means[:, None] - means[None]).max(axis=2)[~np.eye(4, dtype=bool)].min() > 5   # four new colours
    assert not np.array_equal(out.tri_albedo, scan.tri_albedo) and out.tri_albedo.dtype == np.uint8
    half = recolour_scene(scan, 0.5, np.random.default_rng(3), source=clean)   # by instance: all of it or none
    for inst in (0, 1):
        m = scan.tri_instance == inst
        changed = (half.tri_albedo[m] != scan.tri_albedo[m]).any(axis=1)
        assert changed.all() or not changed.any()


def test_recoloured_evaluation_frames_are_their_own_set(small_env_config):
    """``recolour_all`` renders the same poses of the same houses with new colours (the labels and
    depth are those of the plain set), and refuses a training set."""
    from calnav.eval.segmenter.data import render_frames

    cfg = SegDataConfig(resolution=(32, 24), scenes=1, walk_steps=2)
    plain = render_frames(small_env_config, cfg, "val", 4, 0, progress=False)
    recol = render_frames(small_env_config, cfg, "val", 4, 0, progress=False, recolour_all=True)
    assert np.array_equal(plain.labels, recol.labels) and np.array_equal(plain.depth, recol.depth)
    assert np.abs(plain.rgb.astype(int) - recol.rgb).mean() > 10
    with pytest.raises(ValueError, match="recolour_all is an evaluation shift"):
        render_frames(small_env_config, cfg, "val", 4, 0, progress=False, rebalance=True, recolour_all=True)


def test_camera_shift_is_fixed_and_changes_the_frames():
    from calnav.eval.segmenter.appearance import camera_shift

    rgb = (np.random.default_rng(0).random((3, 24, 32, 3)) * 255).astype(np.uint8)
    a, b = camera_shift(rgb, 7), camera_shift(rgb, 7)
    assert np.array_equal(a, b) and a.dtype == np.uint8 and a.shape == rgb.shape
    assert np.abs(a.astype(int) - rgb).mean() > 5
    assert np.array_equal(camera_shift(rgb[1:], 7)[0], camera_shift(rgb[1:2], 7)[0])


def test_ablation_table_renders_the_records(tmp_path):
    import json

    from calnav.eval.segmenter.ablation import ablation_table

    for row, ev, miou in (("all", "camera", 0.4), ("baseline", "clean", 0.5), ("baseline", "camera", 0.2),
                          ("baseline", "recoloured", 0.1)):
        (tmp_path / f"{row}_{ev}.json").write_text(json.dumps({"miou": miou, "miou_goal_structure": miou + 0.1,
                                                               "ece": 0.01}))
    (tmp_path / "baseline.card.json").write_text(json.dumps({"train_wall_s": 90.0}))
    lines = ablation_table(tmp_path).splitlines()
    assert lines[2:] == ["| baseline | clean | 0.500 | 0.600 | 0.010 | 1.5 min |",
                         "| baseline | scanned + camera shift | 0.200 | 0.300 | 0.010 | 1.5 min |",
                         "| baseline | scanned, houses recoloured | 0.100 | 0.200 | 0.010 | 1.5 min |",
                         "| all | scanned + camera shift | 0.400 | 0.500 | 0.010 | - |"]
    with pytest.raises(ValueError, match="holds no"):
        ablation_table(tmp_path / "empty")


@pytest.mark.parametrize("folder", ["shipped", "full", "full_h100", "rgbd_full_h100", "rgbd_full_h100_test2000", "f8000",
                                    "f4000", "f2000", "rgbd_f8000"])
def test_the_weights_readme_holds_the_rendered_ablation_tables(folder):
    """agent/weights/README.md's ablation tables are the committed records rendered, not typed."""
    from pathlib import Path

    from calnav.eval.segmenter.ablation import ablation_table

    root = Path(__file__).resolve().parents[3]
    assert ablation_table(root / "agent/weights/ablation" / folder) in (root / "agent/weights/README.md").read_text()


def _record(confusions, frames="f"):
    """An eval record of two classes (a, b), both goal+structure, from per-house confusions."""
    import numpy as np

    from calnav.mapping.metrics import iou_of_confusion

    iou = iou_of_confusion(np.sum(confusions, axis=0))
    return {"per_class_iou": {"a": iou[0], "b": iou[1]}, "classes_in_miou_goal_structure": ["a", "b"],
            "scene_confusion": confusions, "frames_sha256": frames,
            "miou": float(iou.mean()), "miou_goal_structure": float(iou.mean()), "ece": 0.0}


def test_paired_miou_difference_by_hand():
    """Two houses of 4 pixels, labels a a b b each; rows = predicted, columns = true.
    A is right on 3 of 4 in house 0 ([[2,1],[0,1]]: IoU a 2/3, b 1/2) and on all of house 1;
    B is right everywhere. Pooled A: TP (4, 3), a predicted 5 / true 4, b predicted 3 / true 4:
    IoU a 4/5, b 3/4, mIoU 0.775; B 1. Difference 0.225. Leaving house 0 out: both perfect,
    0; house 1 out: 1 - (2/3 + 1/2) / 2 = 5/12. Jackknife SE = sqrt(1/2 * 2 * (5/24)^2) = 5/24."""
    from calnav.eval.segmenter.ablation import paired_miou_difference

    a = _record([[[2, 1], [0, 1]], [[2, 0], [0, 2]]])
    b = _record([[[2, 0], [0, 2]], [[2, 0], [0, 2]]])
    diff, se, houses = paired_miou_difference(a, b)
    assert diff == pytest.approx(0.225) and se == pytest.approx(5 / 24) and houses == 2
    assert paired_miou_difference(b, a)[0] == pytest.approx(-0.225)
    with pytest.raises(ValueError, match="different frames"):
        paired_miou_difference(a, _record(b["scene_confusion"], frames="g"))
    with pytest.raises(ValueError, match="no scene_confusion"):
        paired_miou_difference(a, {k: v for k, v in b.items() if k != "scene_confusion"})


def test_ablation_table_pairs_rows_with_the_reference_on_the_same_frames(tmp_path):
    import json

    from calnav.eval.segmenter.ablation import ablation_table

    a = _record([[[2, 1], [0, 1]], [[2, 0], [0, 2]]])
    b = _record([[[2, 0], [0, 2]], [[2, 0], [0, 2]]])
    (tmp_path / "shipped_clean.json").write_text(json.dumps(a))
    (tmp_path / "recolour25_clean.json").write_text(json.dumps(b))
    (tmp_path / "recolour25_scanned.json").write_text(json.dumps(b))   # no reference on this set
    lines = ablation_table(tmp_path).splitlines()
    assert lines[0].endswith("| goal+structure - shipped (SE) |")
    assert lines[2] == "| shipped | clean | 0.775 | 0.775 | 0.000 | - | - |"
    assert lines[3] == "| recolour25 | clean | 1.000 | 1.000 | 0.000 | - | +0.225 (0.208) |"
    assert lines[4] == "| recolour25 | scanned | 1.000 | 1.000 | 0.000 | - | - |"


def test_heldout_tables_render_the_records_by_hand(tmp_path):
    import json

    from calnav.eval.segmenter.ablation import heldout_tables

    keys = ("accuracy", "miou", "miou_goal_structure", "ece", "tl_ece", "mece", "brier", "mean_confidence")
    rec = {k: 0.1 * (i + 1) for i, k in enumerate(keys)} | {"per_class_iou": {"a": 0.5, "b": None}}
    (tmp_path / "learned_rgbd.scanned.eval2000.json").write_text(json.dumps(rec))
    (tmp_path / "gt.eval2000.json").write_text(json.dumps(rec | {"accuracy": 1.0}))
    (tmp_path / "learned_rgbd.eval500.json").write_text(json.dumps(rec))   # another size: not in this table
    lines = heldout_tables(tmp_path).splitlines()
    assert lines[2] == "| learned_rgbd | scanned | 0.100 | 0.200 | 0.300 | 0.400 | 0.500 | 0.600 | 0.700 | 0.800 |"
    assert lines[3].startswith("| gt | clean | 1.000 | 0.200 |") and len(lines) == 9
    assert lines[5:] == ["| class | learned_rgbd scanned |", "|---|---:|", "| a | 0.500 |", "| b | - |"]
    with pytest.raises(ValueError, match="holds no"):
        heldout_tables(tmp_path, frames=300)


def test_the_weights_readme_holds_the_rendered_heldout_tables():
    from pathlib import Path

    from calnav.eval.segmenter.ablation import heldout_tables

    root = Path(__file__).resolve().parents[3]
    assert heldout_tables(root / "agent/weights") in (root / "agent/weights/README.md").read_text()
