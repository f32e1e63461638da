"""mapping.metrics: hand-computed cases for every metric, the paper's majority-class failure
case, ignore_index, bin edges, streaming == one-shot, a naive cross-check, and bad input."""
import numpy as np
import pytest

from calnav.mapping import metrics as M

# Case A (K = 2, one sample per bin):
#   probs              label  pred  conf  bin  correct
#   [0.9, 0.1]           0     0    0.9    9     1
#   [0.8, 0.2]           1     0    0.8    8     0
#   [0.3, 0.7]           1     1    0.7    7     1
#   [0.6, 0.4]           0     0    0.6    6     1
# ECE = TL-ECE = (|1-.9| + |0-.8| + |1-.7| + |1-.6|) / 4 = 1.6 / 4 = 0.4
# mECE: class 0 {s0, s3}: (0.1 + 0.4) / 2 = 0.25; class 1 {s1, s2}: (0.8 + 0.3) / 2 = 0.55;
#       mean = 0.4
# Brier: s0 .01+.01 = .02; s1 .64+.64 = 1.28; s2 .09+.09 = .18; s3 .16+.16 = .32 -> 1.8/4 = 0.45
# accuracy 3/4; IoU_0 = TP 2 / (2 + FP 1 + FN 0) = 2/3; IoU_1 = 1 / (1 + 0 + 1) = 1/2;
# mIoU = 7/12
PROBS_A = np.array([[0.9, 0.1], [0.8, 0.2], [0.3, 0.7], [0.6, 0.4]])
LABELS_A = np.array([0, 1, 1, 0])

# Case B (K = 3, every confidence 0.55 -> one bin, separates ECE / TL-ECE / mECE):
#   s0 [.55 .45 0] label 0 pred 0 correct;  s1 [.55 0 .45] label 2 pred 0 wrong
#   s2 [0 .55 .45] label 1 pred 1 correct;  s3 [.45 .55 0] label 1 pred 1 correct
# ECE: acc 3/4, conf .55 -> 0.2
# TL-ECE: pred 0 {s0, s1}: 2/4 |.5 - .55| = .025; pred 1 {s2, s3}: 2/4 |1 - .55| = .225 -> 0.25
# mECE: class 0 {s0}: .45; class 1 {s2, s3}: .45; class 2 {s1}: .55 -> 1.45 / 3
PROBS_B = np.array([[0.55, 0.45, 0.0], [0.55, 0.0, 0.45], [0.0, 0.55, 0.45], [0.45, 0.55, 0.0]])
LABELS_B = np.array([0, 2, 1, 1])


def test_case_a_every_metric():
    assert M.ece(PROBS_A, LABELS_A) == pytest.approx(0.4)
    assert M.tl_ece(PROBS_A, LABELS_A) == pytest.approx(0.4)
    assert M.mece(PROBS_A, LABELS_A) == pytest.approx(0.4)
    assert M.brier(PROBS_A, LABELS_A) == pytest.approx(0.45)
    assert M.accuracy(PROBS_A, LABELS_A) == pytest.approx(0.75)
    assert M.miou(PROBS_A, LABELS_A) == pytest.approx(7 / 12)
    np.testing.assert_allclose(M.per_class_iou(PROBS_A, LABELS_A), [2 / 3, 1 / 2])


def test_case_b_separates_ece_tl_ece_mece():
    assert M.ece(PROBS_B, LABELS_B) == pytest.approx(0.2)
    assert M.tl_ece(PROBS_B, LABELS_B) == pytest.approx(0.25)
    assert M.mece(PROBS_B, LABELS_B) == pytest.approx(1.45 / 3)
    # IoU: class 0 TP 1, FP 1 (s1), FN 0 -> 1/2; class 1: 2/2 = 1; class 2: TP 0, FN 1 -> 0
    assert M.miou(PROBS_B, LABELS_B) == pytest.approx((0.5 + 1.0 + 0.0) / 3)
    assert M.miou(PROBS_B, LABELS_B, classes=[0, 1]) == pytest.approx(0.75)


def test_majority_class_failure_case():
    """Always predicting the majority class with its frequency as confidence: ECE ~ 0 but mECE
    large -- the paper's argument for mECE. 90 % class 0, 10 % class 1:
    ECE = |0.9 - 0.9| = 0; mECE = (|1 - .9| + |0 - .9|) / 2 = 0.5."""
    labels = np.array([0] * 90 + [1] * 10)
    probs = np.tile([0.9, 0.1], (100, 1))
    assert M.ece(probs, labels) == pytest.approx(0.0, abs=1e-12)
    assert M.mece(probs, labels) == pytest.approx(0.5)
    assert M.accuracy(probs, labels) == pytest.approx(0.9)
    assert M.miou(probs, labels) == pytest.approx((0.9 + 0.0) / 2)


def test_confidence_one_falls_in_last_bin():
    # [1, 0] label 1 (wrong, conf 1.0) and [.95, .05] label 0 (right): both in bin 9 ->
    # acc .5, conf .975 -> ECE .475 (separate bins would give (1 + .05) / 2 = .525)
    probs = np.array([[1.0, 0.0], [0.95, 0.05]])
    labels = np.array([1, 0])
    assert M.ece(probs, labels) == pytest.approx(0.475)
    stats = M.CalibrationStats(2).update(probs, labels)
    assert stats.count.sum(axis=(1, 2)).tolist() == [0] * 9 + [2]


def test_left_edge_is_closed():
    # uniform over 10 classes -> conf exactly 0.1 -> bin 1 (not 0); the second sample has
    # conf .15 (bin 1). Together: acc 1/2, conf .125 -> ECE .375 (bin 0 would give .525).
    a = np.full(10, 0.1)
    b = np.array([0.15, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.05, 0.1])
    probs, labels = np.stack([a, b]), np.array([0, 9])
    assert M.ece(probs, labels) == pytest.approx(0.375)
    stats = M.CalibrationStats(10).update(probs, labels)
    assert stats.count.sum(axis=(1, 2))[1] == 2
    # 0.5 exactly: bin 5
    stats = M.CalibrationStats(2).update(np.array([[0.5, 0.5]]), np.array([0]))
    assert np.argmax(stats.count.sum(axis=(1, 2))) == 5


def test_ignore_index_drops_samples_even_with_bad_rows():
    probs = np.vstack([PROBS_A, [[np.nan, np.nan]], [[0.2, 0.8]]])
    labels = np.concatenate([LABELS_A, [-1, -1]])
    for fn in (M.ece, M.tl_ece, M.mece, M.brier, M.accuracy, M.miou):
        assert fn(probs, labels, ignore_index=-1) == pytest.approx(fn(PROBS_A, LABELS_A))
    with pytest.raises(ValueError, match="no samples"):
        M.ece(PROBS_A, np.full(4, 7), ignore_index=7)


def test_mece_skips_classes_absent_from_labels():
    # class 2 is predicted but never a label: mECE averages over classes 0 and 1 only
    probs = np.array([[0.8, 0.1, 0.1], [0.1, 0.1, 0.8]])
    labels = np.array([0, 1])
    # class 0: |1 - .8| = .2; class 1: |0 - .8| = .8 -> .5
    assert M.mece(probs, labels) == pytest.approx(0.5)
    # mIoU: labels-present convention -> classes 0, 1 (IoU 1, 0); "either" adds class 2 (IoU 0)
    assert M.miou(probs, labels) == pytest.approx(0.5)
    assert M.miou(probs, labels, present="either") == pytest.approx(1 / 3)


def _naive(probs, labels, n_bins):
    conf, pred = probs.max(1), probs.argmax(1)
    bins = np.minimum(np.floor(conf * n_bins).astype(int), n_bins - 1)
    ok = pred == labels
    n = len(labels)

    def ece_of(mask_fn, groups):
        total = 0.0
        for g in groups:
            for b in range(n_bins):
                m = (bins == b) & mask_fn(g)
                if m.any():
                    total += m.sum() * abs(ok[m].mean() - conf[m].mean())
        return total

    k = probs.shape[1]
    ece = ece_of(lambda g: np.ones(n, bool), [0]) / n
    tl = ece_of(lambda g: pred == g, range(k)) / n
    per = [ece_of(lambda g, c=c: labels == c, [0]) / (labels == c).sum() for c in range(k) if (labels == c).any()]
    onehot = np.eye(k)[labels]
    return ece, tl, float(np.mean(per)), float(((probs - onehot) ** 2).sum(1).mean())


def test_matches_naive_implementation_and_streaming(monkeypatch):
    rng = np.random.default_rng(0)
    k, n = 5, 3000
    logits = rng.normal(size=(n, k)) * 2
    probs = np.exp(logits) / np.exp(logits).sum(1, keepdims=True)
    labels = rng.integers(0, k, n)
    monkeypatch.setattr(M, "CHUNK_ROWS", 700)  # exercise chunking
    for n_bins in (10, 15):
        ece, tl, me, br = _naive(probs, labels, n_bins)
        assert M.ece(probs, labels, n_bins) == pytest.approx(ece)
        assert M.tl_ece(probs, labels, n_bins) == pytest.approx(tl)
        assert M.mece(probs, labels, n_bins) == pytest.approx(me)
        assert M.brier(probs, labels, n_bins) == pytest.approx(br)
    stats = M.CalibrationStats(k)
    for part in np.array_split(np.arange(n), 7):
        stats.update(probs[part].astype(np.float32), labels[part])
    assert stats.ece() == pytest.approx(M.ece(probs, labels), abs=1e-6)
    assert stats.summary()["n"] == n


@pytest.mark.parametrize("probs, labels, match", [
    (np.ones((3, 2)) / 2, np.zeros(4, int), "disagree on N"),
    (np.ones(4) / 2, np.zeros(4, int), r"\(N, K\)"),
    (np.array([[np.nan, 1.0]]), np.array([0]), "NaN"),
    (np.array([[2.0, -1.0]]), np.array([0]), r"\[0, 1\]"),
    (np.array([[0.7, 0.7]]), np.array([0]), "sum to 1"),
    (np.array([[0.5, 0.5]]), np.array([2]), "class ids"),
    (np.array([[0.5, 0.5]]), np.array([-1]), "class ids"),
    (np.array([[0.5, 0.5]]), np.array([0.0]), "integer"),
    (np.array([[1, 0]]), np.array([0]), "floating"),
    (np.zeros((0, 2)), np.zeros(0, int), "no samples"),
])
def test_bad_input(probs, labels, match):
    with pytest.raises(ValueError, match=match):
        M.ece(probs, labels)


def test_bad_options():
    with pytest.raises(ValueError, match="present"):
        M.miou(PROBS_A, LABELS_A, present="bogus")
    with pytest.raises(ValueError, match="classes"):
        M.miou(PROBS_A, LABELS_A, classes=[5])
    with pytest.raises(ValueError, match="n_bins"):
        M.CalibrationStats(2, n_bins=0)


# ------------------------------------------------------------------ differentiable (torch)
def test_dece_approaches_ece_as_temperatures_vanish():
    import torch

    from calnav.mapping.calibration.metrics_torch import dece, mdece

    # under-confident at low confidence, over-confident at high: bin gaps change sign, so soft
    # binning (large t_b) really differs from hard binning
    rng = np.random.default_rng(1)
    n, k = 4000, 4
    conf = rng.uniform(0.3, 1.0, n)
    top = rng.integers(0, k, n)
    probs = np.repeat(((1 - conf) / (k - 1))[:, None], k, axis=1)
    probs[np.arange(n), top] = conf
    right = rng.random(n) < np.clip(1.3 - conf, 0, 1)
    labels = np.where(right, top, (top + rng.integers(1, k, n)) % k)
    p, y = torch.tensor(probs), torch.tensor(labels)
    hard_ece, hard_mece = M.ece(probs, labels), M.mece(probs, labels)
    errors = [abs(float(dece(p, y, t_a=1e4, t_b=t)) - hard_ece) for t in (1e-1, 1e-2, 1e-5)]
    assert errors[-1] < 1e-3 < errors[0]
    assert float(mdece(p, y, t_a=1e4, t_b=1e-5)) == pytest.approx(hard_mece, abs=1e-3)
    # the authors' temperatures: close to ECE, and differentiable
    pt = p.clone().requires_grad_(True)
    value = dece(pt, y) + 0.5 * mdece(pt, y)
    value.backward()
    assert torch.isfinite(pt.grad).all() and pt.grad.abs().sum() > 0
    assert abs(float(dece(p, y)) - hard_ece) < 0.05


# Case V (K = 3, void = -1): the authors' mIoU convention against calnav's.
#   s0 [.7 .2 .1] label 0   pred 0 correct
#   s1 [.1 .8 .1] label 1   pred 1 correct
#   s2 [.6 .3 .1] label 1   pred 0 wrong: FP of 0, FN of 1
#   s3 [.1 .2 .7] void      pred 2: a void false positive of 2 (authors only)
#   s4 [.2 .7 .1] void      pred 1: a void false positive of 1 (authors only)
# calnav (void dropped, classes in the labels {0, 1}): IoU_0 = 1 / (1 + 1) = 1/2,
#   IoU_1 = 1 / (1 + 1) = 1/2 -> 1/2.
# authors (class 0 excluded, classes labelled or predicted {1, 2}): IoU_1 = 1 / (1 + 0 + 1 + 1) = 1/3,
#   IoU_2 = 0 / (0 + 0 + 0 + 1) = 0 -> 1/6; with nothing excluded IoU_0 = 1/2 joins: 5/18.
PROBS_V = np.array([[0.7, 0.2, 0.1], [0.1, 0.8, 0.1], [0.6, 0.3, 0.1], [0.1, 0.2, 0.7], [0.2, 0.7, 0.1]])
LABELS_V = np.array([0, 1, 1, -1, -1])


def test_authors_miou_convention_hand_computed():
    assert M.miou(PROBS_V, LABELS_V, ignore_index=-1) == pytest.approx(0.5)
    assert M.miou(PROBS_V, LABELS_V, ignore_index=-1, present="either") == pytest.approx(0.5)
    assert M.miou(PROBS_V, LABELS_V, ignore_index=-1, convention="authors") == pytest.approx(1 / 6)
    assert M.miou(PROBS_V, LABELS_V, ignore_index=-1, convention="authors", exclude=()) == pytest.approx(5 / 18)
    stats = M.CalibrationStats(3).update(PROBS_V, LABELS_V, ignore_index=-1, count_ignored=True)
    np.testing.assert_array_equal(stats.void_pred, [0, 1, 1])
    np.testing.assert_allclose(stats.per_class_iou_authors(), [np.nan, 1 / 3, 0.0])
    # the calibration metrics never see void samples, counted or not
    plain = M.CalibrationStats(3).update(PROBS_V, LABELS_V, ignore_index=-1)
    assert plain.mece() == stats.mece() and plain.n == stats.n == 3
    assert plain.void_pred.sum() == 0


def test_authors_miou_streams_and_rejects_bad_options():
    a = M.CalibrationStats(3).update(PROBS_V[:3], LABELS_V[:3], ignore_index=-1, count_ignored=True)
    a.update(PROBS_V[3:], LABELS_V[3:], ignore_index=-1, count_ignored=True)
    assert a.miou(convention="authors") == pytest.approx(1 / 6)
    with pytest.raises(ValueError, match="convention must be one of calnav, authors"):
        M.miou(PROBS_V, LABELS_V, ignore_index=-1, convention="paper")
    with pytest.raises(ValueError, match="exclude must be class ids"):
        a.miou(convention="authors", exclude=[3])
    bad = PROBS_V.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="ignored"):
        M.CalibrationStats(3).update(bad, LABELS_V, ignore_index=-1, count_ignored=True)


def test_error_bins_hand_computed():
    # case A: bins 9 (correct, .9), 8 (wrong, .8), 7 (correct, .7), 6 (correct, .6)
    correct, wrong, wrong_conf = M.CalibrationStats(2).update(PROBS_A, LABELS_A).error_bins()
    np.testing.assert_array_equal(correct, [0, 0, 0, 0, 0, 0, 1, 1, 0, 1])
    np.testing.assert_array_equal(wrong, [0, 0, 0, 0, 0, 0, 0, 0, 1, 0])
    assert wrong_conf[8] == pytest.approx(0.8) and wrong_conf.sum() == pytest.approx(0.8)
