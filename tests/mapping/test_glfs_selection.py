"""GLFS model selection (mapping.calibration.selection) on hand-made validation histories, and
train_glfs's selection rules, fixed gates, initial temperature and class weighting."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from calnav.mapping.calibration.flat_obs import FlatObservations
from calnav.mapping.calibration.glfs_train import GLFSTrainConfig, _check_points, class_weights, train_glfs
from calnav.mapping.calibration.selection import CheckpointSelector, ValidationScore

# A hand-made validation history; check 0 is the initial parameters (mIoU 0.600).
#   check  loss   mIoU    mECE
#     0    1.00   0.600   0.200
#     1    0.90   0.610   0.150   best loss so far; best mIoU so far; mECE admissible (0.610 >= 0.595)
#     2    0.80   0.598   0.120   best loss; mIoU no better; mECE admissible (0.598 >= 0.595): best
#     3    0.70   0.590   0.090   best loss; mECE lower but 0.590 < 0.595: NOT admissible
#     4    0.75   0.605   0.110   loss no better; mIoU no better (0.605 < 0.610); mECE 0.110 < 0.120: best
#     5    0.72   0.596   0.115
#     6    0.71   0.595   0.100   admissible at exactly 0.5 points below: best under constrained
HISTORY = [(1.00, 0.600, 0.200), (0.90, 0.610, 0.150), (0.80, 0.598, 0.120), (0.70, 0.590, 0.090),
           (0.75, 0.605, 0.110), (0.72, 0.596, 0.115), (0.71, 0.595, 0.100)]


def _run(rule: str, patience: int, tolerance: float = 0.5) -> CheckpointSelector:
    sel = CheckpointSelector(rule, patience, tolerance)
    for loss, miou, mece in HISTORY:
        sel.update(ValidationScore(loss, miou, mece))
        if sel.stop:
            break
    return sel


@pytest.mark.parametrize("rule, patience, kept, checks_seen, stops", [
    # val_loss: improves at 1, 2, 3; 4, 5, 6 are worse than 0.70 -> patience 3 stops at check 6
    ("val_loss", 3, 3, 7, True),
    ("val_loss", 2, 3, 6, True),           # stale after checks 4 and 5 -> stops at 5
    # val_miou: best at 1; checks 2..4 are no better -> patience 3 stops at check 4
    ("val_miou", 3, 1, 5, True),
    ("val_miou", 10, 1, 7, False),         # no stop: all checks seen, still check 1
    # constrained (0.5 points): 1, 2 improve; 3 inadmissible (stale 1); 4 improves; 5 stale; 6 improves
    ("constrained", 3, 6, 7, False),
    ("constrained", 1, 2, 4, True),        # check 3 is inadmissible -> stale 1 = patience -> stops at 3
])
def test_selection_rules_keep_the_right_checkpoint_and_stop(rule, patience, kept, checks_seen, stops):
    sel = _run(rule, patience)
    assert sel.best_index == kept
    assert len(sel.scores) == checks_seen
    assert sel.stop == stops


def test_constrained_tolerance_and_initial_checkpoint():
    # with a 2-point tolerance check 3 (0.590 >= 0.580) is admissible and has the lowest mECE
    assert _run("constrained", 10, tolerance=2.0).best_index == 3
    # with tolerance 0, only checks at or above the initial 0.600 mIoU count: 1 (0.150) and 4 (0.110)
    assert _run("constrained", 10, tolerance=0.0).best_index == 4
    # every later check worse than the initial parameters: the initial ones are kept
    sel = CheckpointSelector("constrained", 2)
    for s in [(1.0, 0.6, 0.2), (0.9, 0.5, 0.1), (0.8, 0.6, 0.3)]:
        sel.update(ValidationScore(*s))
    assert sel.best_index == 0 and sel.stop


def test_selector_bad_input():
    with pytest.raises(ValueError, match="valid: val_loss, val_miou, constrained"):
        CheckpointSelector("best", 3)
    with pytest.raises(ValueError, match="patience"):
        CheckpointSelector("val_loss", 0)
    with pytest.raises(ValueError, match="tolerance_points"):
        CheckpointSelector("constrained", 3, -1.0)
    sel = CheckpointSelector("val_loss", 1)
    sel.update(ValidationScore(1, 0.5, 0.1))
    sel.update(ValidationScore(2, 0.5, 0.1))
    with pytest.raises(RuntimeError, match="stopped"):
        sel.update(ValidationScore(0.5, 0.5, 0.1))


def test_check_points_spread_over_the_epoch():
    assert _check_points(9, 3) == {2, 5, 8}
    assert _check_points(10, 1) == {9}
    assert _check_points(2, 3) == {0, 1}        # fewer batches than checks: one check per batch at most


K = 4


def _flat(n: int, seed: int, copies: int = 3) -> FlatObservations:
    """Voxels whose observations are noisy logits of the true class (copies per voxel)."""
    rng = np.random.default_rng(seed)
    y = rng.choice(K, n, p=[0.55, 0.25, 0.15, 0.05])
    z = rng.normal(0, 1.5, (n * copies, K)).astype(np.float32)
    z[np.arange(n * copies), np.repeat(y, copies)] += 1.5
    ones = torch.ones(n * copies)
    return FlatObservations(torch.from_numpy(z), torch.arange(n).repeat_interleave(copies), ones * 2.0, ones * 10.0,
                            ones, torch.from_numpy(y).long())


@pytest.mark.parametrize("rule", ["val_loss", "val_miou", "constrained"])
def test_train_glfs_keeps_the_checkpoint_its_rule_picks(rule):
    train, val = _flat(1500, 0), _flat(600, 1)
    cfg = GLFSTrainConfig(epochs=3, batch_voxels=300, lr=0.05, patience=20, selection=rule, val_per_epoch=2)
    params, hist = train_glfs(train, val, cfg, progress=False)
    n = len(hist.val_loss)
    assert n == 1 + 3 * 2 and len(hist.val_miou) == len(hist.val_mece) == len(hist.val_epoch) == n
    assert hist.val_epoch == pytest.approx([0, 0.4, 1.0, 1.4, 2.0, 2.4, 3.0])   # 5 batches: after 2 (round(2.5)) and 5
    b = hist.best_check
    if rule == "val_loss":
        assert hist.val_loss[b] == pytest.approx(min(hist.val_loss), abs=1e-5)
    elif rule == "val_miou":
        assert hist.val_miou[b] == pytest.approx(max(hist.val_miou), abs=1e-5)
    else:
        ok = [i for i in range(n) if hist.val_miou[i] >= hist.val_miou[0] - 0.005 - 1e-12]
        assert b in ok and hist.val_mece[b] == pytest.approx(min(hist.val_mece[i] for i in ok), abs=1e-5)
    # the returned parameters are the kept checkpoint's
    from calnav.mapping.calibration.glfs_train import GLFSModel, validation_score
    s = validation_score(GLFSModel.from_params(params), val, class_weights(train.class_frequency()), cfg.eta)
    assert s.miou == pytest.approx(hist.val_miou[b], abs=1e-6) and s.mece == pytest.approx(hist.val_mece[b], abs=1e-6)


def test_train_glfs_authors_fixed_gates_initial_tau_and_unweighted_nll():
    train, val = _flat(800, 2), _flat(300, 3)
    cfg = GLFSTrainConfig(epochs=2, batch_voxels=200, learn_gates=False, init_g=0.0, init_eps=0.0, init_tau=0.4,
                          selection="val_miou", class_weighting="none", grad_clip=1.0, patience=5)
    params, hist = train_glfs(train, val, cfg, progress=False)
    assert params.g == 0.0 and params.eps == 0.0
    frozen = GLFSTrainConfig(epochs=1, batch_voxels=200, init_tau=0.4, lr=1e-9, selection="val_loss")
    p0, _ = train_glfs(train, val, frozen, progress=False)
    np.testing.assert_allclose(p0.tau, 0.4, rtol=1e-4)          # starts (and, at lr 1e-9, stays) at 0.4
    np.testing.assert_array_equal(class_weights(np.array([0.5, 0.5, 0.0]), "none").numpy(), [1, 1, 0])
    with pytest.raises(ValueError, match="valid: log_inverse_frequency, none"):
        GLFSTrainConfig(class_weighting="inverse")
    with pytest.raises(ValueError, match="valid: val_loss, val_miou, constrained"):
        GLFSTrainConfig(selection="loss")
    with pytest.raises(ValueError, match="init_tau"):
        GLFSTrainConfig(init_tau=0.0)
