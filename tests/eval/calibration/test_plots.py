"""mapping.metrics.reliability (hand-computed case) and eval.calibration.plots (each figure writes a
readable PNG, also with empty bins and NaN metric rows)."""
import math
import warnings

import matplotlib.image as mpimg
import numpy as np
import pytest

from calnav.mapping import metrics as M
from calnav.eval.calibration import plots as P

# K = 2, n_bins = 4 (edges 0, .25, .5, .75, 1; bins 0 and 1 are empty since K = 2 => h >= .5):
#   probs        label  pred  conf  bin  correct
#   [0.9, 0.1]     0     0    0.9    3     1
#   [0.8, 0.2]     1     0    0.8    3     0
#   [0.4, 0.6]     1     1    0.6    2     1
#   [0.3, 0.7]     0     1    0.7    2     0
#   [0.5, 0.5]    -1     (ignored)
# overall: count [0, 0, 2, 2], acc [nan, nan, .5, .5], conf [nan, nan, .65, .85]
# ECE = .5 * .15 + .5 * .35 = .25
# by true class 0 {s0 bin 3, s3 bin 2}: count [0,0,1,1], acc [-,-,0,1], conf [-,-,.7,.9] -> ECE .4
# by true class 1 {s1 bin 3, s2 bin 2}: count [0,0,1,1], acc [-,-,1,0], conf [-,-,.6,.8] -> ECE .6
# mECE = .5
PROBS = np.array([[0.9, 0.1], [0.8, 0.2], [0.4, 0.6], [0.3, 0.7], [0.5, 0.5]])
LABELS = np.array([0, 1, 1, 0, -1])
NAN = np.nan


def _table():
    return M.reliability(PROBS, LABELS, n_bins=4, ignore_index=-1)


def test_reliability_hand_computed():
    t = _table()
    np.testing.assert_allclose(t.edges, [0, 0.25, 0.5, 0.75, 1.0])
    np.testing.assert_array_equal(t.count, [0, 0, 2, 2])
    assert np.issubdtype(t.count.dtype, np.integer)
    np.testing.assert_allclose(t.accuracy, [NAN, NAN, 0.5, 0.5])
    np.testing.assert_allclose(t.confidence, [NAN, NAN, 0.65, 0.85])
    assert t.class_count.shape == t.class_accuracy.shape == t.class_confidence.shape == (2, 4)
    np.testing.assert_array_equal(t.class_count, [[0, 0, 1, 1], [0, 0, 1, 1]])
    np.testing.assert_allclose(t.class_accuracy, [[NAN, NAN, 0, 1], [NAN, NAN, 1, 0]])
    np.testing.assert_allclose(t.class_confidence, [[NAN, NAN, 0.7, 0.9], [NAN, NAN, 0.6, 0.8]])
    assert t.ece == pytest.approx(0.25)
    assert t.ece == pytest.approx(M.ece(PROBS, LABELS, n_bins=4, ignore_index=-1))
    assert t.mece == pytest.approx(0.5)
    assert t.mece == pytest.approx(M.mece(PROBS, LABELS, n_bins=4, ignore_index=-1))
    np.testing.assert_allclose(t.class_ece(), [0.4, 0.6])
    np.testing.assert_allclose(t.centers, [0.125, 0.375, 0.625, 0.875])


def test_reliability_streaming_and_absent_class():
    stats = M.CalibrationStats(3, n_bins=4)
    stats.update(np.pad(PROBS[:2], ((0, 0), (0, 1))), LABELS[:2])
    stats.update(np.pad(PROBS[2:4], ((0, 0), (0, 1))), LABELS[2:4])
    t = stats.reliability()
    np.testing.assert_array_equal(t.count, [0, 0, 2, 2])
    assert t.class_count.shape == (3, 4) and t.class_count[2].sum() == 0
    assert np.isnan(t.class_accuracy[2]).all() and np.isnan(t.class_confidence[2]).all()
    assert t.mece == pytest.approx(0.5)                     # class 2 absent: skipped
    empty = M.CalibrationStats(2, n_bins=3).reliability()
    assert empty.count.sum() == 0 and np.isnan(empty.accuracy).all() and math.isnan(empty.ece)


def _check_png(path):
    assert path.exists() and path.stat().st_size > 0
    img = mpimg.imread(path)
    assert img.shape[0] > 100 and img.shape[1] > 100


def _other_table():
    rng = np.random.default_rng(0)
    logits = rng.normal(size=(200, 3)) * 2
    probs = np.exp(logits) / np.exp(logits).sum(axis=1, keepdims=True)
    return M.reliability(probs, rng.integers(0, 3, size=200), n_bins=10)


def test_plot_reliability(tmp_path):
    tables = {"rbu": M.reliability(np.pad(PROBS[:4], ((0, 0), (0, 1))), LABELS[:4], n_bins=10),
              "glfs": _other_table()}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = P.plot_reliability(tables, tmp_path / "sub" / "rel.png", title="test")
        out2 = P.plot_reliability_per_class(tables, ["wall", "chair", "bed"], tmp_path / "sub" / "cls.png")
    assert out == tmp_path / "sub" / "rel.png" and out2 == tmp_path / "sub" / "cls.png"
    _check_png(out)
    _check_png(out2)


def test_plot_calibration_vs_accuracy(tmp_path):
    rows = []
    rng = np.random.default_rng(1)
    for seg in ("segformer", "mask2former"):
        for strat in ("rbu", "averaging", "histogram", "geometric_mean", "glfs", "mystery"):
            for cal in ("none", "temperature_2d", "temperature_3d", "vector_3d", "learned"):
                v = rng.uniform(0.0, 0.5, size=5)
                rows.append({"segmenter": seg, "strategy": strat, "calibration": cal, "miou": 0.3 + v[0],
                             "ece": v[1], "tl_ece": v[2], "mece": v[3], "brier": v[4]})
    rows.append({"segmenter": "segformer", "strategy": "rbu", "calibration": "none", "miou": NAN,
                 "ece": NAN, "tl_ece": NAN, "mece": NAN, "brier": NAN})
    rows.append({"segmenter": "segformer", "strategy": "glfs", "calibration": "odd", "miou": 0.5,
                 "ece": 0.1, "tl_ece": NAN, "mece": 0.2, "brier": 0.3})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = P.plot_calibration_vs_accuracy(rows, tmp_path / "a" / "b" / "fig4.png", title="Fig. 4")
    _check_png(out)


def _rows():
    """Two segmenters: fixed rows (best mIoU 0.70 = averaging/none) and three GLFS variants."""
    rows = []
    for seg in ("a", "b"):
        rows += [{"segmenter": seg, "strategy": "rbu", "calibration": "none", "miou": 0.69, "mece": 0.20},
                 {"segmenter": seg, "strategy": "averaging", "calibration": "none", "miou": 0.70, "mece": 0.10},
                 {"segmenter": seg, "strategy": "averaging", "calibration": "vector_3d", "miou": 0.60, "mece": 0.04},
                 {"segmenter": seg, "strategy": "glfs", "calibration": "learned", "miou": 0.66, "mece": 0.05},
                 {"segmenter": seg, "strategy": "glfs", "calibration": "constrained", "miou": 0.6955, "mece": 0.08},
                 {"segmenter": seg, "strategy": "glfs", "calibration": "val_miou", "miou": 0.6990, "mece": 0.09}]
    rows[-2] = dict(rows[-2], miou=0.694)      # segmenter b: constrained is 0.6 points below -> out
    return rows


def test_glfs_pick_rule_hand_computed():
    from calnav.eval.calibration.report import glfs_pick

    picks = glfs_pick(_rows())
    # a: within 0.5 points of 0.70 -> constrained (0.6955) and val_miou (0.699); lowest mECE: constrained
    assert picks["a"]["best_fixed"] == "averaging/none" and picks["a"]["variants_within"] == ["constrained", "val_miou"]
    assert picks["a"]["pick"] == "constrained" and picks["a"]["lowest_mece_within"] == "glfs/constrained"
    # b: constrained at 0.694 is 0.6 points below -> only val_miou
    assert picks["b"]["pick"] == "val_miou" and picks["b"]["lowest_mece_within_value"] == pytest.approx(0.09)
    nothing = [r for r in _rows() if r["segmenter"] == "a" and r["calibration"] != "constrained"
               and r["calibration"] != "val_miou"]
    assert glfs_pick(nothing)["a"]["pick"] is None


def test_glfs_tradeoff_and_error_plots(tmp_path):
    hist = {"val_mece": [0.1, 0.08, 0.07], "val_miou": [0.7, 0.69, 0.68], "best_check": 1}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = P.plot_glfs_tradeoff(_rows(), {"a": {"learned": hist}}, tmp_path / "t.png")
        stats = M.CalibrationStats(2).update(PROBS[:4], LABELS[:4])
        correct, wrong, wconf = stats.error_bins()
        edges = np.linspace(0, 1, 11)
        out2 = P.plot_error_vs_confidence({"rbu": (edges, correct, wrong, float(wconf.sum() / wrong.sum())),
                                           "glfs": (edges, correct, np.zeros(10, int), NAN)}, tmp_path / "e.png")
    _check_png(out)
    _check_png(out2)


def test_tau_curve_minima_and_files(tmp_path):
    from calnav.eval.calibration.tau_curve import curve_minima, write_tau_curves

    # minima: index 1 (0.2 < 0.5, 0.3), the plateau 4-5 once (at 4), and the right end (0.05 < 0.4)
    assert curve_minima([1, 2, 3, 4, 5, 6, 7, 8], [0.5, 0.2, 0.3, 0.35, 0.1, 0.1, 0.4, 0.05]) == [1, 4, 7]
    assert curve_minima([1, 2, 3], [0.3, 0.3, 0.3]) == [0]       # flat (histogram): one plateau
    curves = {"seg": {"temperature": [0.01, 1.0, 300.0], "rbu": {"mece": [0.3, 0.1, 0.2], "miou": [0.5, 0.5, 0.4]}}}
    paths = write_tau_curves(tmp_path, curves, {"seg": {"rbu": 1.0}})
    assert (tmp_path / "tau_curve.csv").read_text().splitlines()[2] == "seg,rbu,1,0.100000,0.500000"
    _check_png(paths[1])
