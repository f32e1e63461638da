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
    with pytest.raises(ValueError, match="^unknown data.eval_appearance 'phone'; valid choices: none, camera$"):
        SegDataConfig(eval_appearance="phone")


def test_default_cache_keys_are_unchanged():
    """The default config's training and evaluation caches keep the names they had before the
    levers existed; recolouring changes the training key only, the eval shift no key."""
    from calnav.eval.segmenter.data import cache_path

    cfg = load_config("configs/segmenter.yaml", [], sections=SEGMENTER_SECTIONS)
    train = cache_path(cfg.env, cfg.data, "train", 20000, 0, False, True)
    test = cache_path(cfg.env, cfg.data, "test", 500, 1000, False, False)
    assert (train.name, test.name) == ("train_20000_2043cc7d04a3.npz", "test_500_40fbbe894513.npz")
    recol = dataclasses.replace(cfg.data, recolour_fraction=0.5)
    camera = dataclasses.replace(cfg.data, eval_appearance="camera")
    assert cache_path(cfg.env, recol, "train", 20000, 0, False, True) != train
    assert cache_path(cfg.env, recol, "test", 500, 1000, False, False) == test
    assert cache_path(cfg.env, camera, "test", 500, 1000, False, False) == test


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

    for row, ev, miou in (("all", "camera", 0.4), ("baseline", "clean", 0.5), ("baseline", "camera", 0.2)):
        (tmp_path / f"{row}_{ev}.json").write_text(json.dumps({"miou": miou, "miou_goal_structure": miou + 0.1,
                                                               "ece": 0.01}))
    (tmp_path / "baseline.card.json").write_text(json.dumps({"train_wall_s": 90.0}))
    lines = ablation_table(tmp_path).splitlines()
    assert lines[2:] == ["| baseline | clean | 0.500 | 0.600 | 0.010 | 1.5 min |",
                         "| baseline | scanned + camera shift | 0.200 | 0.300 | 0.010 | 1.5 min |",
                         "| all | scanned + camera shift | 0.400 | 0.500 | 0.010 | - |"]
    with pytest.raises(ValueError, match="holds no"):
        ablation_table(tmp_path / "empty")
