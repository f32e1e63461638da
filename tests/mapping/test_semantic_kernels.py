"""The voxel map's compiled per-observation loops (mapping.semantic_kernels) against the numpy /
torch passes they replaced, kept here as the reference: the same values bit for bit (same
operations in the same dtypes), on random inputs (hypothesis) and on hand-made edge cases."""
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from calnav.mapping import frame_geometry as fg
from calnav.mapping import semantic_kernels as kernels
from calnav.mapping.fusion import ObservationTerms, get_strategy
from calnav.mapping.registry import FUSIONS
from calnav.mapping.scaling import scale_logits
from calnav.mapping.weighting import WeightingParams, lut_cells, sample_weights

K = 5
SEEDS = st.integers(0, 2**32 - 1)


# ----------------------------------------------------------------- numpy / torch references
def ref_accumulate(acc, flat, z, weight, lut_m, dist, angle, strategy, slices, count_ch, mu):
    """The torch path: strategy increments (w times the LUT by argmax z), cat, index_add_."""
    z_t, w = torch.from_numpy(z), torch.from_numpy(weight)
    if lut_m is not None:
        params = WeightingParams(lut=torch.from_numpy(lut_m))
        w = sample_weights("lut", z_t.max(dim=1).indices, torch.from_numpy(dist), torch.from_numpy(angle), params) * w
    inc = strategy.increments(ObservationTerms(z_t, mu), w)
    val = torch.cat([inc[a] for a in slices] + [torch.ones(len(flat), 1)], dim=1)
    keep = flat >= 0
    torch.from_numpy(acc).index_add_(0, torch.from_numpy(flat[keep]), val[torch.from_numpy(keep)])


def ref_incidence_angles(depth, k, pix, offset):
    """The numpy ``frame_geometry.incidence_angles`` before the kernel."""
    h, w = depth.shape
    flat = np.append(depth.ravel(), np.float32(0))
    off_image = h * w
    u, v = pix % w, pix // w
    z = flat[pix]
    grads = []
    for coord, size, step in ((u, w, offset), (v, h, offset * w)):
        zp = flat[np.where(coord + offset < size, pix + step, off_image)]
        zm = flat[np.where(coord >= offset, pix - step, off_image)]
        ok_p, ok_m = zp > 0, zm > 0
        dp, dm = zp - z, z - zm
        adp, adm = np.abs(dp), np.abs(dm)
        one_sided = np.where(ok_p & (~ok_m | (adp <= adm)), dp, np.where(ok_m, dm, np.float32(0)))
        smooth = ok_p & ok_m & (np.abs(dp - dm) <= fg.SMOOTH_JUMP_RATIO * np.maximum(adp, adm))
        grads.append(np.where(smooth, np.float32(0.5) * (dp + dm), one_sided) * np.float32(1.0 / offset))
    zu, zv = grads
    du, dv = (u - k[0, 2]).astype(np.float32), (v - k[1, 2]).astype(np.float32)
    nz = du * zu + dv * zv + z
    fx, fy = np.float32(k[0, 0]), np.float32(k[1, 1])
    n2 = (fx * zu) ** 2 + (fy * zv) ** 2 + nz * nz
    r2 = (du / fx) ** 2 + (dv / fy) ** 2 + np.float32(1)
    cos = z / np.maximum(np.sqrt(n2 * r2), np.finfo(np.float32).tiny)
    return np.degrees(np.arccos(np.minimum(cos, np.float32(1)))).astype(np.float32)


def ref_associate(pc, k, w, h, depth, band):
    x, y, z = pc.T
    inv_z = 1.0 / np.where(z > 0, z, np.float32(1))
    u = np.rint((k[0, 0] * x + k[0, 1] * y) * inv_z + k[0, 2]).astype(np.int64)
    v = np.rint(k[1, 1] * y * inv_z + k[1, 2]).astype(np.int64)
    ok = (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    pix = np.where(ok, v * w + u, 0)
    dm = depth.ravel()[pix]
    ok &= (dm > 0) & (np.abs(z - dm) <= band)
    sel = np.flatnonzero(ok)
    return sel, pix[sel], np.sqrt(np.einsum("ij,ij->i", pc[sel], pc[sel]))


def ref_candidates(pts, depth, far, shift_m, shift, dims, in_frame, res3, origin):
    """The numpy ``SemanticVoxelMap._candidates`` body (after the rotation) before the kernel."""
    res = 1 << shift
    depth = np.where(depth <= 0, far, depth)
    p = np.maximum(pts * depth + shift_m[:, None], 0)
    g = p.astype(np.int32)
    b = np.minimum(g >> shift, (dims - 1).astype(np.int32)[:, None])
    loc = g & (res - 1)
    lin = (b[2] * dims[1] + b[1]) * dims[0] + b[0]
    local = (loc[2] * res + loc[1]) * res + loc[0]
    ok = np.flatnonzero(in_frame[lin])
    ids = lin[ok].astype(np.int64) * res3 + local[ok]
    stamp = np.full(in_frame.size * res3, -1, np.int64)
    order = np.arange(len(ids))
    stamp[ids] = order   # numpy: the last of repeated indices wins
    win = np.flatnonzero(stamp[ids] == order)
    return ids[win], g[:, ok[win]].T + origin


# ----------------------------------------------------------------------------- tests
@pytest.mark.parametrize("name", FUSIONS.names())
@pytest.mark.parametrize("lut", [False, True])
@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, n=st.integers(0, 60))
def test_accumulate_adds_the_torch_increments_bit_for_bit(name, lut, seed, n):
    rng = np.random.default_rng(seed)
    strategy = get_strategy(name)
    channels = strategy.channels(K)
    slices, start = {}, 0
    for a, c in channels.items():
        slices[a] = slice(start, start + c)
        start += c
    count_ch, mu = start, 1e-3
    voxels = 80
    flat = rng.permutation(voxels)[:n].astype(np.int64)
    flat[rng.random(n) < 0.1] = -1   # blocks Open3D dropped
    logits = (rng.standard_normal((n, K)) * rng.choice([0.1, 3, 50], size=(n, 1))).astype(np.float32)
    z = scale_logits(torch.from_numpy(logits), torch.from_numpy(rng.uniform(0.3, 3, K).astype(np.float32))).numpy()
    tie = rng.random(n) < 0.3
    z[tie, 1] = z[tie, 3] = z[tie].max(axis=1) + 1   # tied maxima: the first wins (torch's argmax)
    weight = rng.uniform(0, 2, n).astype(np.float32)
    dist = rng.uniform(0, 7, n).astype(np.float32)
    angle = rng.uniform(0, 90, n).astype(np.float32)
    lut_m = rng.uniform(-0.5, 2, (K, 5, 3)).astype(np.float32) if lut else None
    acc0 = rng.standard_normal((voxels, count_ch + 1)).astype(np.float32)
    expected, got = acc0.copy(), acc0.copy()
    ref_accumulate(expected, flat, z, weight, lut_m, dist, angle, strategy, slices, count_ch, mu)

    terms = ObservationTerms(torch.from_numpy(z), mu)
    empty = np.zeros((0, K), np.float32)
    log_p = terms.log_p.numpy() if "A" in slices else empty
    p = terms.p.numpy() if "B" in slices and not strategy.votes else empty
    cell, flat_lut = np.zeros(0, np.int64), np.zeros(0, np.float32)
    if lut:
        params = WeightingParams(lut=torch.from_numpy(lut_m))
        cell = lut_cells(torch.from_numpy(dist), torch.from_numpy(angle), params).numpy()
        flat_lut = np.ascontiguousarray(np.maximum(lut_m, 0).reshape(-1))
    off = {a: slices[a].start if a in slices else -1 for a in ("A", "B", "W")}
    kernels.accumulate(got, flat, z, log_p, p, weight, cell, flat_lut, 15, off["A"], off["B"], strategy.votes,
                       off["W"], count_ch)
    assert got.tobytes() == expected.tobytes()


@settings(max_examples=30, deadline=None)
@given(seed=SEEDS, offset=st.integers(1, 3))
def test_incidence_angles_match_the_numpy_reference(seed, offset):
    rng = np.random.default_rng(seed)
    h, w = 12, 16
    depth = rng.uniform(0.5, 4, (h, w)).astype(np.float32)
    depth[rng.random((h, w)) < 0.2] = 0   # holes: one-sided and missing neighbours
    depth[:, w // 2:] += np.float32(rng.choice([0, 1.5]))   # a depth discontinuity
    k = np.array([[14.0, 0, 7.3], [0, 13.0, 5.6], [0, 0, 1]])
    pix = rng.choice(h * w, 40).astype(np.int64)
    got = fg.incidence_angles(depth, k, pix, offset)
    assert got.dtype == np.float32 and got.tobytes() == ref_incidence_angles(depth, k, pix, offset).tobytes()


def test_incidence_angles_refuse_pixels_off_the_image():
    depth = np.ones((4, 5), np.float32)
    with pytest.raises(ValueError, match="pixels must lie in the 5x4 image"):
        fg.incidence_angles(depth, np.eye(3), np.array([20]), 1)


@settings(max_examples=30, deadline=None)
@given(seed=SEEDS)
def test_association_matches_the_numpy_reference(seed):
    rng = np.random.default_rng(seed)
    h, w, n = 12, 16, 200
    k = np.array([[14.0, 0.5, 7.3], [0, 13.0, 5.6], [0, 0, 1]])
    depth = rng.uniform(0.5, 3, (h, w)).astype(np.float32)
    depth[rng.random((h, w)) < 0.2] = 0
    pc = rng.uniform(-2, 3, (n, 3)).astype(np.float32)
    pc[:20, 2] = 0   # on the camera plane: rejected
    band = np.float32(0.3)
    sel, pix, dist = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.float32)
    m = kernels.associate(pc, k[0, 0], k[0, 1], k[0, 2], k[1, 1], k[1, 2], w, h, depth.ravel(), band, sel, pix, dist)
    rsel, rpix, rdist = ref_associate(pc, k, w, h, depth, band)
    assert m == len(rsel) and np.array_equal(sel[:m], rsel) and np.array_equal(pix[:m], rpix)
    assert dist[:m].tobytes() == rdist.astype(np.float32).tobytes()


@settings(max_examples=30, deadline=None)
@given(seed=SEEDS)
def test_candidates_match_the_numpy_reference(seed):
    rng = np.random.default_rng(seed)
    shift, n = 2, 300
    res = 1 << shift
    blocks = rng.integers(0, 4, (12, 3))
    table = fg.BlockTable(blocks)
    origin = (table.low * res).astype(np.int32)
    pts = rng.uniform(-0.5, 1, (3, n)).astype(np.float32)
    depth = rng.uniform(0, 10, n).astype(np.float32)
    depth[rng.random(n) < 0.1] = 0
    depth[1::7] = depth[::7][: len(depth[1::7])]   # repeated points: one voxel, the last wins
    pts[:, 1::7] = pts[:, ::7][:, : pts[:, 1::7].shape[1]]
    shift_m = rng.uniform(0, 6, 3).astype(np.float32)
    far, res3 = np.float32(1e3), res ** 3
    stamp = np.empty(table.in_frame.size * res3, np.int32)
    g, slot, ids, keys = (np.empty((3, n), np.int32), np.empty(n, np.int64), np.empty(n, np.int64),
                          np.empty((n, 3), np.int32))
    m = kernels.candidates(pts, depth, far, shift_m, shift, table.dims.astype(np.int64), table.in_frame, stamp, res3,
                           origin, g, slot, ids, keys)
    rids, rkeys = ref_candidates(pts, depth, far, shift_m, shift, table.dims, table.in_frame, res3, origin)
    assert m == len(rids) and np.array_equal(ids[:m], rids) and np.array_equal(keys[:m], rkeys)


def test_gather_rows_copies_and_checks_only_the_rows_read():
    logits = np.arange(24, dtype=np.float32).reshape(6, 4)
    logits[5, 2] = np.nan   # never read
    out = np.empty((3, 4), np.float32)
    assert kernels.gather_rows(logits, np.array([4, 0, 4]), out)
    assert np.array_equal(out, logits[[4, 0, 4]])
    for bad in (np.nan, np.inf, -np.inf):
        logits[0, 3] = bad
        assert not kernels.gather_rows(logits, np.array([4, 0]), out[:2])


def test_clean_depth_zeroes_what_is_outside_the_range():
    depth = np.array([[0.5, 0.0, np.nan, 12.0], [np.inf, 0.1, 0.3, 10.0]], np.float32)
    out = fg.clean_depth(depth, 0.3, 10.0)
    assert np.array_equal(out, np.array([[0.5, 0, 0, 0], [0, 0, 0.3, 10.0]], np.float32))
    assert np.isnan(depth[0, 2]) and depth[0, 1] == 0   # the input is not changed
    ok = np.full((2, 3), 1.5, np.float32)
    out = fg.clean_depth(ok, 0.3, 10.0)
    assert np.shares_memory(out, ok) and np.array_equal(out, ok)   # nothing to clean: no copy


def test_the_lut_must_match_its_bin_edges():
    """The compiled look-up indexes the flat table without bounds checks: a table whose shape
    disagrees with the bin edges is refused where it is built (``lut_table``)."""
    from calnav.mapping.weighting import lut_table

    ok = WeightingParams(lut=torch.ones(K, 5, 3))
    assert lut_table(ok).shape == (K, 5, 3)
    for bad in (torch.ones(K, 5, 2), torch.ones(K, 15)):
        with pytest.raises(ValueError, match=r"the LUT M must have shape \(K, n_dist, n_angle\) = \(K, 5, 3\)"):
            lut_table(WeightingParams(lut=bad))
