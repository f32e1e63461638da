"""Observation cache (mapping.calibration.obs_cache): reservoir cap, CSR save/load, padding, errors."""
import numpy as np
import pytest
import torch

from calnav.mapping.fusion import fuse
from calnav.mapping.calibration.obs_cache import ObsCache

K = 3
VOX = 0.05


def _record(cache, keys, rng, weights=False):
    keys = np.asarray(keys, np.int32)
    logits = rng.normal(size=(len(keys), K)).astype(np.float32)
    dist = rng.uniform(0.5, 5, len(keys))
    angle = rng.uniform(0, 90, len(keys))
    cache.record(keys, logits, dist, angle, rng.uniform(0.5, 2, len(keys)).astype(np.float32) if weights else None)
    return logits


def test_records_in_temporal_order_without_cap():
    rng = np.random.default_rng(0)
    cache = ObsCache(K, VOX, cap=None)
    seen = {}
    for frame in range(5):
        keys = [[0, 0, 0], [1, 2, 3], [-4, 5, -6]][: frame % 3 + 1]
        logits = _record(cache, keys, rng)
        for key, row in zip(map(tuple, keys), logits):
            seen.setdefault(key, []).append(row.astype(np.float16).astype(np.float32))
    assert len(cache) == 3 and cache.num_observations == 5 + 3 + 1
    padded = cache.to_padded()
    assert padded.logits.shape == (3, 5, K) and padded.mask.sum() == cache.num_observations
    for i, key in enumerate(map(tuple, cache.keys)):
        obs = padded.logits[i][padded.mask[i]].numpy()
        assert np.array_equal(obs, np.stack(seen[key]))
    assert np.allclose(cache.coords, cache.keys * VOX)
    assert padded.weight[padded.mask].eq(1).all() and padded.weight[~padded.mask].eq(0).all()


def test_reservoir_cap_keeps_a_uniform_seeded_subset():
    cap, n = 8, 200
    subsets = []
    for seed in (0, 0, 1):
        rng = np.random.default_rng(42)
        cache = ObsCache(K, VOX, cap=cap, seed=seed)
        for _ in range(n):
            _record(cache, [[1, 1, 1], [2, 2, 2]], rng)
        _record(cache, [[3, 3, 3]], rng)
        assert cache.counts().tolist() == [cap, cap, 1]
        assert cache.n_seen().tolist() == [n, n, 1]
        subsets.append(cache.to_padded().logits[0].numpy())
    assert np.array_equal(subsets[0], subsets[1])  # seeded: reproducible
    assert not np.array_equal(subsets[0], subsets[2])


def test_reservoir_is_uniform_over_time():
    """Each of the n observations of a voxel survives with probability cap / n."""
    cap, n, trials = 4, 40, 300
    kept = np.zeros(n)
    for seed in range(trials):
        cache = ObsCache(K, VOX, cap=cap, seed=seed)
        for t in range(n):
            cache.record(np.zeros((1, 3), np.int32), np.full((1, K), t, np.float32), [1.0], [0.0])
        kept[cache.to_padded().logits[0, :, 0].numpy().astype(int)] += 1
    frac = kept / trials
    assert abs(frac[: n // 2].mean() - frac[n // 2:].mean()) < 0.03
    assert frac.mean() == pytest.approx(cap / n, abs=1e-9)


def test_save_load_roundtrip_with_labels_and_weights(tmp_path):
    rng = np.random.default_rng(1)
    cache = ObsCache(K, VOX, cap=5, seed=3, class_names=("a", "b", "c"))
    for _ in range(9):
        _record(cache, rng.integers(-3, 3, (6, 3)), rng, weights=True)
    cache.set_labels(np.arange(len(cache)) % K)
    loaded = ObsCache.load(cache.save(tmp_path / "cache.npz"))
    assert loaded.class_names == ("a", "b", "c") and loaded.cap == 5 and len(loaded) == len(cache)
    assert np.array_equal(loaded.labels, cache.labels) and np.array_equal(loaded.keys, cache.keys)
    a, b = cache.to_padded(max_T=3), loaded.to_padded(max_T=3)
    for name in ("logits", "mask", "distance_m", "angle_deg", "weight"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name
    assert a.logits.shape[1] == 3
    with pytest.raises(ValueError, match="read-only"):
        _record(loaded, [[0, 0, 0]], rng)


def test_to_padded_chunks_and_fuses():
    rng = np.random.default_rng(2)
    cache = ObsCache(K, VOX, cap=None)
    for _ in range(4):
        _record(cache, rng.integers(0, 4, (10, 3)), rng)
    full = cache.to_padded()
    probs = fuse(full.logits, "averaging", mask=full.mask)
    ids = np.arange(1, len(cache), 2)
    part = cache.to_padded(voxel_ids=ids)
    assert torch.allclose(fuse(part.logits, "averaging", mask=part.mask), probs[ids], atol=1e-6)


def test_errors():
    cache = ObsCache(K, VOX)
    with pytest.raises(ValueError, match="empty"):
        cache.to_padded()
    with pytest.raises(ValueError, match="empty"):
        cache.save("/tmp/never.npz")
    with pytest.raises(ValueError, match="NaN"):
        cache.record(np.zeros((1, 3)), np.array([[0.0, np.nan, 1.0]], np.float32), [1.0], [0.0])
    with pytest.raises(ValueError, match="shape"):
        cache.record(np.zeros((2, 3)), np.zeros((2, K + 1), np.float32), [1.0, 1.0], [0.0, 0.0])
    with pytest.raises(ValueError, match="float16"):
        cache.record(np.zeros((1, 3)), np.full((1, K), 1e6, np.float32), [1.0], [0.0])
    cache.record(np.zeros((1, 3)), np.zeros((1, K), np.float32), [1.0], [0.0])
    with pytest.raises(ValueError, match="one label per cached voxel"):
        cache.set_labels(np.zeros(2))
    with pytest.raises(ValueError, match="cap"):
        ObsCache(K, VOX, cap=0)
