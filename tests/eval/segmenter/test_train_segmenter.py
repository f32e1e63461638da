"""eval.segmenter.train / eval.segmenter.evaluate on a tiny rendered set (16 frames at 64x48):
training lowers the loss, the weights load into the segmenter, an interrupted run resumed from
its checkpoint ends bit-identical to an uninterrupted one, the dataset cache is reused, and
eval-segmenter writes the metrics JSON."""
import json

import numpy as np
import pytest
import torch

from calnav.eval.config import SEGMENTER_SECTIONS, load_config
from calnav.eval.segmenter.data import cache_path, load_or_render

TINY = ["data.frames=16", "data.scenes=2", "data.resolution=64x48", "data.walk_steps=4",
        "data.scanned_fraction=0", "train.epochs=4", "train.batch_size=8", "train.val_frames=4", "train.lr=0.01",
        "env.dataset.train_scenes=2", "env.dataset.val_scenes=1", "env.dataset.test_scenes=1"]


@pytest.fixture(scope="module")
def cfg():
    return load_config("configs/segmenter.yaml", TINY, sections=SEGMENTER_SECTIONS)


@pytest.fixture(scope="module")
def trained(cfg, tmp_path_factory):
    from calnav.eval.segmenter.train import train

    out = tmp_path_factory.mktemp("seg") / "rgbd.pt"
    card = train(cfg, "learned_rgbd", out, progress=False, command="test")
    return out, card


def test_training_lowers_the_loss_and_writes_a_card(trained):
    out, card = trained
    losses = [h["train_loss"] for h in card["history"]]
    assert len(losses) == 4 and losses[-1] < losses[0]
    saved = json.loads(out.with_suffix(".json").read_text())
    for key in ("command", "seed", "train_frames", "resolution", "train_wall_s", "history", "weights_sha256"):
        assert key in saved
    assert saved["train_frames"] == 16 and saved["resolution"] == [64, 48]
    assert "val_miou" in saved["history"][-1]


def test_trained_weights_load_into_the_segmenter(trained, cfg):
    from calnav.agent.segmenters import SegmenterConfig, make_segmenter

    out, _ = trained
    seg = make_segmenter("learned_rgbd", SegmenterConfig(weights=str(out)))
    data = load_or_render(cfg.env, cfg.data, "train", progress=False, rebalance=True)
    logits = seg(data.rgb[0], data.depth[0].astype(np.float32))
    assert logits.shape == (48, 64, 18) and np.isfinite(logits).all()
    assert seg.meta["train_frames"] == 16


def test_an_eval_record_names_the_weights_it_scores(trained, cfg):
    """The record carries the scored weights' sha256 (the card's), not only their path."""
    import dataclasses

    from calnav.eval.segmenter.evaluate import evaluate

    out, card = trained
    weighted = dataclasses.replace(cfg, segmenter=dataclasses.replace(cfg.segmenter, weights=str(out)))
    m = evaluate(weighted, "learned_rgbd", "test", frames=2, progress=False)
    assert m["weights"] == str(out) and m["weights_sha256"] == card["weights_sha256"]
    # per-house confusions: they add up to the scored pixels and give the record's IoUs
    from calnav.mapping.metrics import iou_of_confusion

    per_house = np.asarray(m["scene_confusion"])
    assert per_house.ndim == 3 and per_house.shape[1:] == (18, 18) and per_house.sum() == m["n_pixels"]
    iou = [v if v is not None else np.nan for v in m["per_class_iou"].values()]
    np.testing.assert_allclose(iou_of_confusion(per_house.sum(axis=0)), iou)
    # ... and the frames it scored: the same frames give the same digest, other frames another
    from calnav.eval.segmenter.data import load_or_render
    from calnav.eval.segmenter.evaluate import EVAL_SEED_OFFSET, frames_sha256

    data = load_or_render(cfg.env, cfg.data, "test", frames=2, seed=cfg.data.seed + EVAL_SEED_OFFSET, progress=False)
    assert m["frames_sha256"] == frames_sha256(data)
    data.labels[0, 0, 0] = (int(data.labels[0, 0, 0]) + 1) % 18
    assert frames_sha256(data) != m["frames_sha256"]
    assert evaluate(weighted, "learned_rgbd", "test", frames=2, progress=False)["frames_sha256"] == m["frames_sha256"]


def test_resume_is_bit_identical(trained, cfg, tmp_path):
    from calnav.eval.segmenter.train import checkpoint_path, train

    full, _ = trained
    part = tmp_path / "part.pt"
    assert train(cfg, "learned_rgbd", part, progress=False, stop_after_epoch=2) is None
    assert not part.exists()
    ckpt = torch.load(checkpoint_path(cfg, "learned_rgbd"), weights_only=False)
    assert ckpt["epoch"] == 2 and set(ckpt) >= {"model", "optimizer", "scheduler", "torch_rng", "history"}
    card = train(cfg, "learned_rgbd", part, resume=True, progress=False)
    assert [h["epoch"] for h in card["history"]] == [1, 2, 3, 4]
    a = torch.load(full, weights_only=True)["state_dict"]
    b = torch.load(part, weights_only=True)["state_dict"]
    assert a.keys() == b.keys()
    for key in a:
        assert torch.equal(a[key], b[key]), key


def test_dataset_cache_is_reused(cfg):
    path = cache_path(cfg.env, cfg.data, "train", 16, 0, False, rebalance=True)
    assert path.exists()
    before = path.stat().st_mtime_ns
    data = load_or_render(cfg.env, cfg.data, "train", progress=False, rebalance=True)
    assert path.stat().st_mtime_ns == before
    assert data.rgb.dtype == np.uint8 and data.depth.dtype == np.float16 and data.labels.dtype == np.int8
    assert data.rgb.shape == (16, 48, 64, 3) and data.poses.shape == (16, 4, 4)


def test_eval_segmenter_cli_writes_metrics(tmp_path):
    from calnav.eval.cli import main

    out = tmp_path / "gt.json"
    rc = main(["eval-segmenter", "--segmenter", "gt", "--split", "test", "--frames", "3", "--output", str(out),
               *[o for o in TINY if o.startswith(("data.", "env."))], "segmenter.gt_confidence=0.8"])
    assert rc == 0
    m = json.loads(out.read_text())
    assert m["n_frames"] == 3 and m["resolution"] == [64, 48]
    assert m["accuracy"] == pytest.approx(1.0)
    assert m["ece"] == pytest.approx(0.2, abs=1e-6)    # always right with confidence 0.8
    assert m["mece"] == pytest.approx(0.2, abs=1e-6)
    assert m["miou"] == pytest.approx(1.0)
    for key in ("miou_goal_structure", "per_class_iou", "classes_in_miou", "brier", "tl_ece"):
        assert key in m
    assert m["weights_sha256"] is None   # gt has no weights


def test_train_rejects_unknown_model(cfg, tmp_path):
    from calnav.eval.segmenter.train import train

    with pytest.raises(ValueError, match="trainable models"):
        train(cfg, "gt", tmp_path / "x.pt", progress=False)


def test_gaussian_blur_hand_case():
    """sigma 1 px: radius 2, 1-D weights exp(-x^2 / 2) / 2.48373 for x = -2..2; an impulse spreads
    into their outer product (centre 0.40262^2 = 0.16210), a constant image is unchanged."""
    from calnav.eval.segmenter.train import gaussian_blur

    img = torch.zeros(1, 3, 9, 9)
    img[:, :, 4, 4] = 1.0
    out = gaussian_blur(img, 1.0)
    w = np.exp(-0.5 * np.arange(-2, 3) ** 2) / np.exp(-0.5 * np.arange(-2, 3) ** 2).sum()
    assert w[2] == pytest.approx(0.40262, abs=1e-5)
    np.testing.assert_allclose(out[0, 1, 2:7, 2:7].numpy(), np.outer(w, w), atol=1e-6)
    assert float(out[0, 0, 0, 0]) == 0.0 and float(out.sum()) == pytest.approx(3.0, abs=1e-5)
    flat = torch.full((2, 3, 6, 7), 0.37)
    np.testing.assert_allclose(gaussian_blur(flat, 1.7).numpy(), 0.37, atol=1e-6)


def test_augmentation_blurs_the_chosen_share(cfg):
    """train.blur_prob = 1 blurs every image (an impulse spreads); 0 leaves the stream untouched."""
    import dataclasses

    from calnav.eval.segmenter.train import augment

    rgb = torch.zeros(4, 3, 12, 12)
    rgb[:, :, 6, 6] = 0.5
    labels = torch.zeros(4, 12, 12, dtype=torch.int64)
    quiet = dataclasses.replace(cfg.train, brightness=0.0, contrast=0.0, colour=0.0, rgb_noise_std=0.0, hflip=False,
                                blur_prob=0.0)
    same, _, _ = augment(rgb.clone(), None, labels, torch.Generator().manual_seed(0), quiet, 5.0)
    torch.testing.assert_close(same, rgb)
    blurred, _, _ = augment(rgb.clone(), None, labels, torch.Generator().manual_seed(0),
                            dataclasses.replace(quiet, blur_prob=1.0, blur_sigma_px=2.0), 5.0)
    assert (blurred[:, :, 6, 6] < 0.5).all() and (blurred[:, :, 6, 7] > 0).all()


def test_depth_dropout_blanks_the_chosen_share(cfg):
    """train.depth_dropout_prob = 1 blanks every depth image to 0 (invalid) and leaves rgb alone;
    0 keeps depth; a value outside [0, 1] or NaN is refused."""
    import dataclasses

    from calnav.eval.sections import TrainConfig
    from calnav.eval.segmenter.train import augment

    rgb = torch.full((64, 3, 4, 4), 0.5)
    depth = torch.full((64, 1, 4, 4), 2.0)
    labels = torch.zeros(64, 4, 4, dtype=torch.int64)
    quiet = dataclasses.replace(cfg.train, brightness=0.0, contrast=0.0, colour=0.0, rgb_noise_std=0.0, hflip=False,
                                blur_prob=0.0, depth_noise_std=0.0, depth_dropout_prob=0.0)
    _, kept, _ = augment(rgb.clone(), depth.clone(), labels, torch.Generator().manual_seed(0), quiet, 5.0)
    torch.testing.assert_close(kept, depth)
    out, blank, _ = augment(rgb.clone(), depth.clone(), labels, torch.Generator().manual_seed(0),
                            dataclasses.replace(quiet, depth_dropout_prob=1.0), 5.0)
    assert (blank == 0).all()
    torch.testing.assert_close(out, rgb)
    _, half, _ = augment(rgb.clone(), depth.clone(), labels, torch.Generator().manual_seed(0),
                         dataclasses.replace(quiet, depth_dropout_prob=0.5), 5.0)
    blanked = (half.flatten(1) == 0).all(dim=1)
    assert (blanked | (half.flatten(1) == 2.0).all(dim=1)).all() and 16 < int(blanked.sum()) < 48
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="depth_dropout_prob"):
            TrainConfig(depth_dropout_prob=bad)


def test_depth_ratio_sets_the_depth_branch_width_and_survives_a_save():
    """train.net_depth_ratio scales the depth branch (stem 16 -> 16 channels at 1.0, 8 at the
    default 0.5); the spec round-trips through to_dict / from_dict, a dict saved before the key
    existed loads as 0.5, and a ratio outside (0, 2] or NaN is refused."""
    from calnav.agent.segmenters.network import NetSpec, SegNet
    from calnav.eval.sections import TrainConfig

    wide = SegNet(NetSpec(in_depth=True, depth_ratio=1.0))
    narrow = SegNet(NetSpec(in_depth=True))
    assert wide.depth.channels == [32, 64, 128, 160] and narrow.depth.channels == [16, 32, 64, 80]
    assert NetSpec.from_dict(NetSpec(in_depth=True, depth_ratio=1.0).to_dict()).depth_ratio == 1.0
    old = NetSpec(in_depth=True).to_dict()
    del old["depth_ratio"]
    assert NetSpec.from_dict(old).depth_ratio == 0.5
    out = wide(torch.rand(2, 3, 32, 48), torch.rand(2, 1, 32, 48) * 5)
    assert out.shape == (2, 18, 32, 48)
    for bad in (0.0, -1.0, 2.5, float("nan")):
        with pytest.raises(ValueError, match="net_depth_ratio"):
            TrainConfig(net_depth_ratio=bad)


def test_fine_tuning_starts_from_the_given_weights(trained, cfg, tmp_path):
    """train.init_weights loads the file before the first step: at a vanishing learning rate the
    first epoch's loss is the trained network's, far below a random start's, its weights come
    back unchanged, and the card names the file by its content."""
    import dataclasses

    from calnav.eval.inputs import sha256_file
    from calnav.eval.segmenter.train import train

    src, scratch = trained
    tc = dataclasses.replace(cfg.train, init_weights=str(src), lr=1e-9, epochs=1, val_frames=0)
    card = train(dataclasses.replace(cfg, train=tc), "learned_rgbd", tmp_path / "ft.pt", progress=False)
    assert card["history"][0]["train_loss"] < 0.5 * scratch["history"][0]["train_loss"]
    assert card["init_weights"] == {"path": str(src), "sha256": sha256_file(src)}
    a = torch.load(src, weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "ft.pt", weights_only=True)["state_dict"]
    for key in a:   # BatchNorm running statistics move with the batches; learned tensors do not
        if "running" not in key and a[key].is_floating_point():
            torch.testing.assert_close(a[key].float(), b[key].float(), atol=1e-3, rtol=1e-3)


def test_fine_tuning_refuses_a_file_it_cannot_start_from_before_rendering(trained, cfg, tmp_path):
    import dataclasses

    from calnav.eval.segmenter.train import train

    src, _ = trained
    fresh = dataclasses.replace(cfg.data, seed=cfg.data.seed + 977)   # frames no test has rendered
    cases = [("learned_rgb", {}, ValueError, "not 'learned_rgb'"),
             ("learned_rgbd", {"net_decoder_width": 32}, ValueError, "another shape: decoder_width 64 .train: 32."),
             ("learned_rgbd", {"init_weights": str(tmp_path / "none.pt")}, FileNotFoundError, "none.pt")]
    for model, change, error, message in cases:
        tc = dataclasses.replace(cfg.train, **{"init_weights": str(src), **change})
        with pytest.raises(error, match=message):
            train(dataclasses.replace(cfg, data=fresh, train=tc), model, tmp_path / "x.pt", progress=False)
    assert not cache_path(cfg.env, fresh, "train", 16, fresh.seed, False, rebalance=True).exists()
    assert not (tmp_path / "x.pt").exists()


def test_a_fine_tuning_resumes_only_from_the_same_start(trained, cfg, tmp_path):
    """The checkpoint key holds the start file's content: a retrained file at the same path is
    another run."""
    import dataclasses
    import shutil

    from calnav.eval.segmenter.train import checkpoint_path

    src, _ = trained
    start = tmp_path / "start.pt"
    shutil.copy(src, start)
    tuned = dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, init_weights=str(start)))
    before = checkpoint_path(tuned, "learned_rgbd")
    assert before != checkpoint_path(cfg, "learned_rgbd")
    state = torch.load(start, weights_only=False)
    key = next(k for k, v in state["state_dict"].items() if v.is_floating_point())
    state["state_dict"][key] += 1   # a retrained file
    torch.save(state, start)
    assert checkpoint_path(tuned, "learned_rgbd") != before
