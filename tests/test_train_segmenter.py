"""eval.segmenter.train / eval.segmenter.evaluate on a tiny rendered set (16 frames at 64x48):
training lowers the loss, the weights load into the segmenter, an interrupted run resumed from
its checkpoint ends bit-identical to an uninterrupted one, the dataset cache is reused, and
eval-segmenter writes the metrics JSON."""
import json

import numpy as np
import pytest
import torch

from eval.config import load_config
from eval.segmenter.data import SegmenterExperimentConfig, cache_path, load_or_render

TINY = ["data.frames=16", "data.scenes=2", "data.resolution=64x48", "data.walk_steps=4",
        "train.epochs=4", "train.batch_size=8", "train.val_frames=4", "train.lr=0.01",
        "env.dataset.train_scenes=2", "env.dataset.val_scenes=1", "env.dataset.test_scenes=1"]


@pytest.fixture(scope="module")
def cfg():
    return load_config("configs/segmenter.yaml", TINY, cls=SegmenterExperimentConfig)


@pytest.fixture(scope="module")
def trained(cfg, tmp_path_factory):
    from eval.segmenter.train import train

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
    from agent.segmenters import SegmenterConfig, make_segmenter

    out, _ = trained
    seg = make_segmenter("learned_rgbd", SegmenterConfig(weights=str(out)))
    data = load_or_render(cfg.env, cfg.data, "train", progress=False, rebalance=True)
    logits = seg(data.rgb[0], data.depth[0].astype(np.float32))
    assert logits.shape == (48, 64, 18) and np.isfinite(logits).all()
    assert seg.meta["train_frames"] == 16


def test_resume_is_bit_identical(trained, cfg, tmp_path):
    from eval.segmenter.train import checkpoint_path, train

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
    from eval.cli import main

    out = tmp_path / "gt.json"
    rc = main(["eval-segmenter", "--model", "gt", "--split", "test", "--frames", "3", "--output", str(out),
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


def test_train_rejects_unknown_model(cfg, tmp_path):
    from eval.segmenter.train import train

    with pytest.raises(ValueError, match="trainable models"):
        train(cfg, "gt", tmp_path / "x.pt", progress=False)
