"""agent.projection: the compiled back-projection, cell indices and free rays against the numpy
code they replaced (kept here as the reference), and the obstacle band."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from calnav.agent import projection as pj


def _numpy_backproject(depth, k, pose):
    """The reference: ``projection.backproject`` as numpy did it before the compiled loop."""
    h, w = depth.shape
    pix = np.flatnonzero(depth.reshape(-1) > 0)
    z = depth.reshape(-1)[pix].astype(np.float64)
    v, u = np.divmod(pix, w)
    cam = np.stack([(u - k[0, 2]) * z / k[0, 0], (v - k[1, 2]) * z / k[1, 1], z], axis=1)
    return (cam @ pose[:3, :3].T + pose[:3, 3]).astype(np.float32), pix


def _numpy_free_rays(camera_xy, points, pix, width, obstacle, samples):
    """The reference: ``projection.free_rays`` as numpy did it (a dense key image, argmin per column)."""
    d = points[:, :2].astype(np.float64) - camera_xy
    rng = np.hypot(d[:, 0], d[:, 1])
    key = np.full((int(pix[-1]) // width + 1) * width, np.inf)
    key[pix] = np.where(obstacle, rng, -rng + 1e6)
    key = key.reshape(-1, width)
    row = key.argmin(axis=0)
    cols = np.flatnonzero(np.isfinite(key[row, np.arange(width)]))
    point = np.full(key.size, -1, np.int64)
    point[pix] = np.arange(len(pix))
    ends = d[point[row[cols] * width + cols]]
    seg = camera_xy + ends[:, None, :] * np.linspace(0.0, 1.0, samples)[None, :, None]
    return seg.reshape(-1, 2).astype(np.float32)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), samples=st.integers(1, 6))
def test_compiled_projection_matches_the_numpy_reference(seed, samples):
    """backproject, cell_of and free_rays (compiled) give numpy's results bit for bit: holes,
    whole empty columns and rows, ties between points of one column (the lowest row wins),
    points off the map."""
    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 24, 2)
    depth = rng.uniform(0.2, 6, (h, w)).astype(np.float32)
    depth[rng.random((h, w)) < 0.3] = 0
    depth[:, rng.integers(0, w)] = 0
    if rng.random() < 0.3:
        depth[:] = depth[0]   # equal depths down the columns: tied keys
    k = np.array([[rng.uniform(10, 200), 0, rng.uniform(0, w)], [0, rng.uniform(10, 200), rng.uniform(0, h)],
                  [0, 0, 1]])
    a = rng.uniform(-np.pi, np.pi)
    pose = np.eye(4)
    pose[:3, :3] = np.array([[np.cos(a), 0, np.sin(a)], [np.sin(a), 0, -np.cos(a)], [0, -1, 0]])
    pose[:3, 3] = rng.uniform(-3, 3, 3)
    pts, pix = pj.backproject(depth, k, pose)
    ref_pts, ref_pix = _numpy_backproject(depth, k, pose)
    np.testing.assert_array_equal(pix, ref_pix)
    assert pts.tobytes() == ref_pts.tobytes()
    origin, cell_m, n = rng.uniform(-4, 0, 2), rng.choice([0.05, 0.1, 0.25]), int(rng.integers(1, 60))
    for xy in (pts[:, :2], pts, pts.astype(np.float64)):
        cells, inside = pj.cell_of(xy, origin, cell_m, n)
        cr = np.floor((np.asarray(xy[:, :2], np.float64) - origin) / cell_m).astype(np.int64)
        ref_inside = (cr >= 0).all(axis=1) & (cr < n).all(axis=1)
        np.testing.assert_array_equal(inside, ref_inside)
        np.testing.assert_array_equal(cells, np.where(ref_inside, cr[:, 1] * n + cr[:, 0], 0))
    if len(pix):
        obstacle = rng.random(len(pix)) < 0.5
        free = pj.free_rays(pose[:2, 3], pts, pix, w, obstacle, samples)
        assert free.tobytes() == _numpy_free_rays(pose[:2, 3], pts, pix, w, obstacle, samples).tobytes()
        with pytest.raises(ValueError, match="disagree"):
            pj.free_rays(pose[:2, 3], pts, pix[:-1], w, obstacle, samples)


def test_backproject_and_obstacle_band():
    k = np.array([[2.0, 0, 1.0], [0, 2.0, 1.0], [0, 0, 1]])
    pose = np.eye(4)
    depth = np.array([[1.0, 0.0, 2.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]], np.float32)
    pts, pix = pj.backproject(depth, k, pose)
    np.testing.assert_array_equal(pix, [0, 2])
    np.testing.assert_allclose(pts, [[-0.5, -0.5, 1.0], [1.0, -1.0, 2.0]], atol=1e-6)
    ob = pj.obstacle_points(np.array([[0, 0, 0.1], [0, 0, 0.5], [0, 0, 0.95]]), 0.25, 0.89)
    np.testing.assert_array_equal(ob, [False, True, False])
