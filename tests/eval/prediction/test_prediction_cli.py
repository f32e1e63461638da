"""`calnav collect-maps` / `calnav train-predictor` / `agent.exploration=prediction` end to end on
a few short episodes: the ground-truth targets lie under what the agent maps, collection
resumes, the predictor trains and drives episodes, bad predictor files are one-line errors
before anything is written; AUC / AP against hand-computed cases."""
from __future__ import annotations

import numpy as np
import pytest

from calnav.eval.cli import main
from calnav.eval.prediction.train import auc_ap

pytestmark = pytest.mark.e2e

SMALL = ["env.resolution=64x48", "env.dataset.train_scenes=2", "env.dataset.val_scenes=1",
         "env.dataset.episodes_per_scene=1", "run.workers=1"]


def test_auc_ap_hand_computed():
    # scores 0.9(+) 0.8(-) 0.7(+) 0.1(-): pairs (+ over -): (0.9>0.8, 0.9>0.1, 0.7<0.8, 0.7>0.1) -> 3/4
    # AP: ranked + - + -: precision at the positives 1/1 and 2/3 -> (1 + 2/3) / 2
    auc, ap = auc_ap(np.array([0.9, 0.8, 0.7, 0.1]), np.array([1, 0, 1, 0], bool))
    assert auc == pytest.approx(0.75) and ap == pytest.approx((1 + 2 / 3) / 2)
    assert auc_ap(np.array([0.5, 0.5]), np.array([1, 0], bool))[0] == pytest.approx(0.5)   # a tie counts half
    assert np.isnan(auc_ap(np.array([0.5, 0.2]), np.array([0, 0], bool))[0])


@pytest.fixture(scope="module")
def maps(tmp_path_factory):
    out = tmp_path_factory.mktemp("maps") / "gt_ndf"
    assert main(["collect-maps", "--episodes", "0:2", "--steps", "50", "--every", "25", "--output", str(out),
                 "agent.segmenter=gt", "agent.map_type=ndf", *SMALL]) == 0
    return out


def test_targets_lie_under_what_the_agent_maps(maps, capsys):
    """With ground-truth segmentation, the goal cells the agent has mapped overlap the
    rasterised ground truth best unshifted (a frame or half-cell error would move the best
    shift off (0, 0))."""
    from calnav.common.npz import load_versioned_npz
    from calnav.eval.prediction.collect import MAPS_FORMAT

    overlap = {}
    for f in sorted((maps / "episodes").glob("*.npz")):
        arrays, meta = load_versioned_npz(f, MAPS_FORMAT)
        x, y, names = arrays["inputs"][-1], arrays["targets"][-1], meta["spec"]["class_names"]
        assert arrays["inputs"].shape[0] == 2 and list(arrays["steps"]) == [25, 50]
        for dr in range(-2, 3):
            for dc in range(-2, 3):
                overlap[(dr, dc)] = overlap.get((dr, dc), 0) + sum(
                    int(((x[4 + names.index(g)] > 128) & np.roll(y[i] > 0, (dr, dc), (0, 1))).sum())
                    for i, g in enumerate(meta["spec"]["goal_categories"]))
    assert max(overlap, key=overlap.get) == (0, 0) and overlap[(0, 0)] > 0, overlap
    # a rerun resumes: nothing left to collect
    assert main(["collect-maps", "--episodes", "0:2", "--steps", "50", "--every", "25", "--output", str(maps),
                 "agent.segmenter=gt", "agent.map_type=ndf", *SMALL]) == 0
    assert "(0 collected now)" in capsys.readouterr().out


def test_train_then_explore_by_prediction(maps, tmp_path, capsys):
    weights = tmp_path / "predictor.pt"
    assert main(["train-predictor", "--data", str(maps), "--epochs", "1", "--output", str(weights)]) == 0
    assert "mean AUC" in capsys.readouterr().out and weights.with_suffix(".json").is_file()
    run = ["objectnav", "--agent", "peanut", "--episodes", "0:1", "agent.segmenter=gt", "agent.map_type=ndf",
           "agent.exploration=prediction", *SMALL]
    assert main([*run, "--output", str(tmp_path / "run"), f"agent.predictor_weights={weights}"]) == 0
    from tests.conftest import read_records

    assert read_records(tmp_path / "run")[0]["status"] == "ok"
    capsys.readouterr()
    # bad predictor files: one line, nothing written
    (tmp_path / "junk.pt").write_bytes(b"junk")
    for bad, message in [(tmp_path / "none.pt", "predictor weights not found"),
                         (tmp_path / "junk.pt", "cannot read predictor weights")]:
        assert main([*run, "--output", str(tmp_path / "bad"), f"agent.predictor_weights={bad}"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, err
        assert not (tmp_path / "bad").exists()
    # a predictor trained on the maps of other classes (a label-mapped plugin predicting NYU40's)
    assert main([*run, "--output", str(tmp_path / "bad"), f"agent.predictor_weights={weights}",
                 "agent.segmenter=tests.agent.segmenter_plugins:no_tv"]) == 2
    assert "predicts no tv_monitor" in capsys.readouterr().err


def test_collect_and_train_refuse_bad_arguments(tmp_path, capsys):
    assert main(["collect-maps", "--every", "0", "--output", str(tmp_path / "m"), *SMALL]) == 2
    assert "--every in [1, --steps]" in capsys.readouterr().err
    assert main(["train-predictor", "--data", str(tmp_path), "--output", str(tmp_path / "p.pt")]) == 2
    assert "no collect-maps episodes" in capsys.readouterr().err
