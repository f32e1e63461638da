"""Calibration fitting (2D / 3D temperature, 3D vector scaling), flat fusion, GLFS training."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from calnav.mapping import metrics
from calnav.mapping.calibration.fit import MapObjective, fit_temperature_2d, fit_temperature_3d, fit_vector_3d
from calnav.mapping.calibration.flat_obs import FlatObservations
from calnav.mapping.fusion import fuse, fuse_flat
from calnav.mapping.calibration.glfs_train import GLFSModel, GLFSTrainConfig, glfs_loss, class_weights, train_glfs
from calnav.mapping.calibration.obs_cache import ObsCache
from calnav.mapping.registry import FUSIONS

K = 5


def _sample(n: int, scale: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Logits whose *true* class probabilities are softmax(logits / scale): labels drawn from it."""
    rng = np.random.default_rng(seed)
    z = rng.normal(0, 2.0, (n, K)).astype(np.float32) * scale
    p = torch.softmax(torch.from_numpy(z) / scale, dim=1).numpy().astype(np.float64)
    p /= p.sum(axis=1, keepdims=True)
    y = np.array([rng.choice(K, p=row) for row in p])
    return z, y


def _flat(z: np.ndarray, y: np.ndarray, copies: int) -> FlatObservations:
    """Each voxel observed ``copies`` times with the same logits (repeated frames)."""
    n = len(y)
    logits = torch.from_numpy(np.repeat(z, copies, axis=0))
    voxel = torch.arange(n).repeat_interleave(copies)
    ones = torch.ones(n * copies)
    return FlatObservations(logits, voxel, ones * 2.0, ones * 10.0, ones, torch.from_numpy(y).long())


def test_temperature_2d_recovers_the_generating_temperature():
    z, y = _sample(6000, scale=2.5, seed=0)
    r = fit_temperature_2d(z, y)
    assert r.temperature == pytest.approx(2.5, rel=0.1)
    with pytest.raises(ValueError, match="NaN"):
        fit_temperature_2d(np.full((3, K), np.nan), np.zeros(3, int))
    with pytest.raises(ValueError, match="no labelled pixels"):
        fit_temperature_2d(z[:3], -np.ones(3, int))


def test_3d_temperature_undoes_rbu_double_counting():
    # 4 identical observations per voxel: RBU counts the evidence 4 times, so the calibrated map
    # needs tau ~ 4; the geometric mean divides by the count and needs tau ~ 1.
    z, y = _sample(4000, scale=1.0, seed=1)
    flat = _flat(z, y, copies=4)
    rbu = fit_temperature_3d(flat, "rbu")
    geo = fit_temperature_3d(flat, "geometric_mean")
    assert rbu.temperature == pytest.approx(4.0, rel=0.3)
    assert geo.temperature == pytest.approx(1.0, rel=0.3)
    assert rbu.objective < MapObjective(flat, "rbu")(1.0) / 2       # calibration through the fusion pays
    assert rbu.objective == pytest.approx(MapObjective(flat, "rbu")(rbu.temperature))


def test_histogram_is_invariant_to_a_scalar_temperature():
    z, y = _sample(500, scale=1.0, seed=2)
    r = fit_temperature_3d(_flat(z, y, copies=2), "histogram", grid_points=5, refine_iters=2)
    assert r.flat and r.temperature == 1.0


def test_vector_scaling_never_worsens_its_start_and_fits_per_class():
    z, y = _sample(3000, scale=1.0, seed=3)
    z[:, 2] *= 3.0   # class 2 logits overconfident: its own temperature should rise
    flat = _flat(z, y, copies=1)
    start = MapObjective(flat, "averaging")(1.0)
    r = fit_vector_3d(flat, "averaging", init=1.0, sweeps=2, refine_iters=5)
    assert r.temperature.shape == (K,) and np.all(r.temperature > 0)
    assert r.objective <= start
    assert r.objective == pytest.approx(MapObjective(flat, "averaging")(r.temperature))


def test_3d_scaling_refuses_glfs_and_unknown_objectives():
    z, y = _sample(50, scale=1.0, seed=4)
    flat = _flat(z, y, copies=1)
    with pytest.raises(ValueError, match="glfs learns"):
        fit_temperature_3d(flat, "glfs")
    with pytest.raises(ValueError, match="valid: mece"):
        MapObjective(flat, "rbu", objective="nll")


@pytest.mark.parametrize("strategy", sorted(FUSIONS))
def test_fuse_flat_matches_padded_fuse(strategy):
    rng = np.random.default_rng(5)
    n, t = 40, 6
    logits = torch.from_numpy(rng.normal(0, 3, (n, t, K)).astype(np.float32))
    mask = torch.from_numpy(rng.random((n, t)) < 0.7)
    mask[:, 0] = True
    w = torch.from_numpy(rng.uniform(0.1, 2.0, (n, t)).astype(np.float32))
    gates = {"g": 0.3, "eps": 0.6} if strategy == "glfs" else {}
    tau = torch.linspace(0.5, 2.0, K)
    padded = fuse(logits, strategy, mask=mask, weights=w, temperature=tau, **gates)
    rows, cols = torch.nonzero(mask, as_tuple=True)
    flat = fuse_flat(logits[rows, cols], rows, n, strategy, weights=w[rows, cols], temperature=tau, **gates)
    torch.testing.assert_close(flat, padded, atol=1e-5, rtol=1e-5)
    with pytest.raises(ValueError, match=r"voxel indices must be in \[0, 3\)"):
        fuse_flat(logits[0], torch.arange(t), 3, strategy, **gates)


def _cache_with(labels: np.ndarray, n_obs: int = 3) -> ObsCache:
    cache = ObsCache(K, 0.05, cap=None)
    rng = np.random.default_rng(6)
    keys = np.repeat(np.arange(len(labels))[:, None] * np.array([[1, 0, 0]]), n_obs, axis=0)
    cache.record(keys, rng.normal(0, 1, (len(keys), K)), np.ones(len(keys)), np.zeros(len(keys)))
    cache.set_labels(labels)
    return cache


def test_flat_observations_from_caches_and_bad_input():
    flat = FlatObservations.from_caches([_cache_with(np.array([0, -1, 2, 3])), _cache_with(np.array([1, 1]))])
    assert flat.num_voxels == 5 and len(flat) == 15            # the void voxel is left out
    assert flat.labels.tolist() == [0, 2, 3, 1, 1]
    sub = flat.subset([4, 0])
    assert sub.labels.tolist() == [1, 0] and len(sub) == 6 and sub.voxel.tolist() == [0, 0, 0, 1, 1, 1]
    with pytest.raises(ValueError, match="every voxel is void"):
        FlatObservations.from_caches([_cache_with(np.array([-1, -1]))])
    unlabelled = ObsCache(K, 0.05)
    unlabelled.record(np.zeros((1, 3)), np.zeros((1, K)), np.ones(1), np.zeros(1))
    with pytest.raises(ValueError, match="no ground-truth labels"):
        FlatObservations.from_caches([unlabelled])
    with pytest.raises(ValueError, match="empty"):
        FlatObservations.from_caches([])


def test_class_weights_skip_absent_classes():
    w = class_weights(np.array([0.7, 0.3, 0.0]))
    assert w[2] == 0 and w[1] > w[0] and float(w[:2].mean()) == pytest.approx(1.0)


def test_glfs_training_lowers_its_loss_and_is_seeded():
    # RBU-like double counting: 5 copies of each observation; GLFS must learn to discount them
    z, y = _sample(3000, scale=1.0, seed=7)
    flat = _flat(z, y, copies=5)
    train, val = flat.subset(np.arange(2000)), flat.subset(np.arange(2000, 3000))
    cfg = GLFSTrainConfig(epochs=6, batch_voxels=500, lr=0.05, init_g=1.0, init_eps=1.0, patience=6)
    start = GLFSModel(K, cfg)
    weights = class_weights(train.class_frequency())
    with torch.no_grad():
        loss0 = float(glfs_loss(start(val), val.labels, weights, cfg.eta))
    params, hist = train_glfs(train, val, cfg, progress=False)
    assert hist.val_loss[0] == pytest.approx(loss0, rel=1e-5)
    assert min(hist.val_loss) < 0.8 * loss0
    assert 0 <= params.g <= 1 and 0 <= params.eps <= 1 and (params.M >= 0).all() and (params.tau > 0).all()
    with torch.no_grad():
        fused = GLFSModel.from_params(params)(val).numpy()
        rbu = fuse_flat(val.logits, val.voxel, val.num_voxels, "rbu").numpy()
    assert metrics.mece(fused, val.labels.numpy()) < metrics.mece(rbu, val.labels.numpy())
    again, _ = train_glfs(train, val, cfg, progress=False)
    np.testing.assert_allclose(again.tau, params.tau)
    np.testing.assert_allclose(again.M, params.M)


def test_glfs_training_rejects_mismatched_inputs():
    z, y = _sample(20, scale=1.0, seed=8)
    flat = _flat(z, y, copies=1)
    other = FlatObservations(flat.logits[:, :3], flat.voxel, flat.distance_m, flat.angle_deg, flat.weight,
                             flat.labels.clamp(max=2))
    with pytest.raises(ValueError, match="disagree on K"):
        train_glfs(flat, other, progress=False)
    with pytest.raises(ValueError, match="class names"):
        train_glfs(flat, flat, class_names=("a", "b"), progress=False)
    with pytest.raises(ValueError, match="lr > 0"):
        GLFSTrainConfig(lr=0)
