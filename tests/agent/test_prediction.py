"""agent.prediction: the predictor's input window (pooling, channels, the agent's cell, the
region shortcut), PEANUT's distance-weighted goal choice on hand-computed cases, and the
weight-file checks."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from calnav.agent.prediction import (PredictorNet, PredictorSpec, check_predictor, crop_origin, map_input,
                                     predicted_goal, save_predictor)

CLASSES = ("chair", "bed", "wall")
GOALS = ("chair", "bed")
SPEC = PredictorSpec(CLASSES, GOALS, cell_m=0.2, window_cells=16, stem=8, stages=((8, 1), (16, 1)), width=8)


def _maps(n=40):
    ch = {k: np.zeros((n, n), bool) for k in ("obstacle", "explored", "visited")}
    return ch, np.zeros((len(CLASSES), n, n), np.float32)


def test_map_input_pools_each_channel_as_documented():
    """4 map cells (5 cm) per coarse cell (20 cm); the window (16 coarse = 64 map cells) is
    centred on the agent at map cell (20, 20): corner (-12, -12), so map cell (r, c) falls in
    coarse cell ((r + 12) // 4, (c + 12) // 4)."""
    ch, sem = _maps()
    ch["obstacle"][20, 21] = True
    ch["explored"][20:22, 20:24] = True          # 8 of the 16 map cells of coarse (8, 8)
    ch["visited"][19, 19] = True
    sem[1, 21, 22] = 0.7
    sem[1, 20, 20] = 0.2                         # max-pooled: 0.7
    x = map_input(ch, sem, (20, 20), SPEC, 0.05)
    assert crop_origin((20, 20), SPEC, 4) == (-12, -12)
    assert x.shape == (SPEC.in_channels, 16, 16)
    assert x[0, 8, 8] == 1.0 and x[0].sum() == 1.0                    # obstacle: max
    assert x[1, 8, 8] == pytest.approx(0.5) and x[1].sum() == pytest.approx(0.5)   # explored: fraction
    assert x[2, 8, 8] == 1.0 and x[2].sum() == 1.0                    # the agent's cell
    assert x[3, 7, 7] == 1.0 and x[3].sum() == 1.0                    # visited (19, 19) -> (7, 7)
    assert x[4 + 1, 8, 8] == pytest.approx(0.7) and x[4].sum() == 0   # semantic: max, per class
    # only the region is pooled: the same input when the region holds everything
    np.testing.assert_array_equal(x, map_input(ch, sem, (20, 20), SPEC, 0.05, (slice(19, 22), slice(19, 24))))


def test_map_input_outside_the_map_is_zero_and_checks_classes():
    ch, sem = _maps()
    ch["explored"][:] = True
    x = map_input(ch, sem, (0, 0), SPEC, 0.05)      # corner (-32, -32): the map covers coarse 8..15
    assert x[1, :8].sum() == 0 and x[1, :, :8].sum() == 0 and x[1, 8:, 8:].min() == 1.0
    with pytest.raises(ValueError, match="the map has 2 classes, the predictor reads 3"):
        map_input(ch, sem[:2], (0, 0), SPEC, 0.05)
    with pytest.raises(ValueError, match="not a whole multiple of agent.cell_m"):
        map_input(ch, sem, (0, 0), SPEC, 0.03)


def test_predicted_goal_hand_computed():
    """value = p x exp(-d cell_m / distance_m): p 0.8 at 10 cells (0.5 m) -> 0.8 e^-0.1 = 0.724;
    p 0.9 at 40 cells (2 m) -> 0.9 e^-0.4 = 0.603: the nearer one wins; with distance_m 100 the
    likelier one does. Explored / unreachable cells are never chosen."""
    prob = np.zeros((50, 50), np.float32)
    prob[10, 20], prob[40, 20] = 0.8, 0.9
    d = np.zeros((50, 50))
    d[10, 20], d[40, 20] = 10, 40
    cand = np.ones((50, 50), bool)
    win = (slice(0, 50), slice(0, 50))
    goal, value = predicted_goal(prob, (0, 0), win, d, cand, 5.0, 0.05)
    assert goal == (10, 20) and value == pytest.approx(0.8 * np.exp(-0.1), rel=1e-5)
    assert predicted_goal(prob, (0, 0), win, d, cand, 100.0, 0.05)[0] == (40, 20)
    cand[10, 20] = False                        # explored
    assert predicted_goal(prob, (0, 0), win, d, cand, 5.0, 0.05)[0] == (40, 20)
    d[40, 20] = np.inf                          # unreachable
    assert predicted_goal(prob, (0, 0), win, d, cand, 5.0, 0.05) is None
    # the prediction is placed by its corner: shifted by (5, -3) in a window starting at (5, 0)
    goal, _ = predicted_goal(prob, (10, -3), (slice(5, 55), slice(0, 50)), np.zeros((50, 50)),
                             np.ones((50, 50), bool), 5.0, 0.05)
    assert goal == (40 + 5, 20 - 3)


def test_network_shape_and_weight_checks(tmp_path):
    net = PredictorNet(SPEC).eval()
    assert net(torch.zeros(2, SPEC.in_channels, 16, 16)).shape == (2, 2, 16, 16)
    path = save_predictor(net, tmp_path / "p.pt", {"command": "test"})
    assert check_predictor(path, CLASSES, GOALS, 0.05) == SPEC
    with pytest.raises(ValueError, match="reads a map of the classes chair, bed, wall; this agent's segmenter has chair, bed"):
        check_predictor(path, ("chair", "bed"), GOALS, 0.05)
    with pytest.raises(ValueError, match="predicts no plant"):
        check_predictor(path, CLASSES, ("chair", "plant"), 0.05)
    with pytest.raises(ValueError, match="not a whole multiple"):
        check_predictor(path, CLASSES, GOALS, 0.03)
    with pytest.raises(FileNotFoundError, match="predictor weights not found: .*calnav train-predictor"):
        check_predictor(tmp_path / "none.pt", CLASSES, GOALS, 0.05)
    (tmp_path / "bad.pt").write_bytes(b"junk")
    with pytest.raises(ValueError, match="cannot read predictor weights"):
        check_predictor(tmp_path / "bad.pt", CLASSES, GOALS, 0.05)
    torch.save({"format": 1, "spec": SPEC.to_dict(), "state_dict": {"head.weight": torch.zeros(3)}}, tmp_path / "d.pt")
    with pytest.raises(ValueError, match="damaged predictor weights"):
        check_predictor(tmp_path / "d.pt", CLASSES, GOALS, 0.05)


def test_near_explored_is_a_square_of_the_given_radius():
    from calnav.agent.prediction import near_explored

    e = np.zeros((9, 9), bool)
    e[4, 4] = True
    near = near_explored(e, 2)
    assert near[2:7, 2:7].all() and near.sum() == 25


def test_weights_holding_nan_are_refused_naming_the_file(tmp_path):
    """Predictor weights with a NaN (or inf) tensor load and run but predict NaN everywhere, so the
    prediction agent would quietly act as the frontier agent: they are refused when loaded, by
    the checks (the preflight's check_predictor) and by Predictor itself."""
    from calnav.agent.prediction import Predictor

    net = PredictorNet(SPEC).eval()
    for bad in (float("nan"), float("inf")):
        with torch.no_grad():
            next(net.parameters()).fill_(bad)
        path = save_predictor(net, tmp_path / "nan.pt", {"command": "test"})
        message = (rf"^predictor weights {path} hold NaN or inf \(tensor '[\w.]+'\); create them again with: "
                   rf"calnav train-predictor --data DIR --output {path}$")
        with pytest.raises(ValueError, match=message):
            check_predictor(path, CLASSES, GOALS, 0.05)
        with pytest.raises(ValueError, match=message):
            Predictor(path)
