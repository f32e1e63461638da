"""Compiled (numba) per-observation loops of the voxel map's semantic update: association of
candidate voxels with pixels, depth-image incidence angles, the finiteness check of the logits
read, and the weighted scatter of a frame's increments into the voxels.

Each was a chain of numpy / torch passes over (n,) or (n, K) arrays whose call and allocation
overhead dominated at a frame's few thousand observations. The vectorised transcendental work
(softmax, log) stays in torch (``mapping.fusion.ObservationTerms``): numba's scalar exp / log
are slower, and the same torch ops keep the accumulators what ``fuse`` sums, bit for bit. The
kernels repeat the numpy arithmetic they replace operation by operation in the same dtypes
(tests/mapping/test_semantic_kernels.py holds them to the numpy / torch reference).

The kernels index without bounds checks: their callers (``SemanticVoxelMap``) pass arrays whose
shapes and index ranges they construct.
"""
from __future__ import annotations

import numpy as np

from calnav.common.jit import compiled

_F32_TINY = np.float32(np.finfo(np.float32).tiny)


@compiled
def clean_depth(depth, lo, hi):
    """``depth`` (H * W,) float32 metres, or a copy with every entry outside [lo, hi] (NaN, inf,
    0 included) set to 0 when there is one."""
    for i in range(depth.shape[0]):
        if not lo <= depth[i] <= hi:
            break
    else:
        return depth
    out = depth.copy()
    for j in range(i, depth.shape[0]):
        if not lo <= out[j] <= hi:
            out[j] = 0
    return out


@compiled
def candidates(pts, depth, far, shift_m, shift, dims, in_frame, stamp, res3, origin, g, slot, ids, keys):
    """A frame's unique candidate voxels: the voxel containing each candidate pixel's surface point.

    pts (3, n) float32: the candidate pixels' rays in voxel units, rotated to the world (R ray /
    voxel size); times their depth ``depth`` (n,) float32 metres (invalid entries, <= 0, become
    ``far``), plus ``shift_m`` (3,) float32: voxel coordinates relative to the frame's padded
    block-table corner (dims (3,) blocks, x fastest). Coordinates below 0 are clipped to 0 and
    blocks beyond the table into its last layer (the padding: no frame block there). A voxel is
    kept when its block is ``in_frame`` (prod(dims),) bool; among the points in one voxel the
    last wins. Writes the kept voxels' table id (cell * res3 + voxel in block, x fastest) into
    ``ids`` (n,) int64 and their integer key (+ ``origin`` (3,) int32) into ``keys`` (n, 3)
    int32, in pixel order, and returns their number. Work arrays: stamp (prod(dims) * res3,)
    int32 (need not be clear), g (3, n) int32, slot (n,) int64."""
    res = 1 << shift
    n = pts.shape[1]
    for i in range(n):
        d = depth[i]
        if d <= 0:
            d = far
        cell, local = 0, 0
        for a in range(2, -1, -1):   # z, y, x: x varies fastest
            v = int(max(pts[a, i] * d + shift_m[a], np.float32(0)))   # truncation = floor (v >= 0)
            g[a, i] = v
            cell = cell * dims[a] + min(v >> shift, dims[a] - 1)
            local = local * res + (v & (res - 1))
        slot[i] = -1
        if in_frame[cell]:
            slot[i] = cell * res3 + local
            stamp[slot[i]] = i
    m = 0
    for i in range(n):
        v = slot[i]
        if v >= 0 and stamp[v] == i:
            ids[m] = v
            for a in range(3):
                keys[m, a] = g[a, i] + origin[a]
            m += 1
    return m


@compiled
def associate(pc, fx, skew, cx, fy, cy, width, height, depth, band_m, sel, pix, dist):
    """Candidate voxels whose centre projects onto a pixel that sees the same surface.

    pc (n, 3) float32 voxel centres in the camera frame (metres); pinhole fx, skew, cx, fy, cy
    (pixels, float64); depth (H * W,) float32 metres (0 = invalid); band_m (float32): the
    largest |voxel z - depth|. Writes the kept rows' index into ``sel``, their flat pixel into
    ``pix`` and their camera distance (metres, float32) into ``dist`` (all (n,)); returns the
    number kept."""
    m = 0
    for i in range(pc.shape[0]):
        x, y, z = pc[i, 0], pc[i, 1], pc[i, 2]
        if not z > 0:
            continue
        inv_z = np.float32(1) / z
        u = np.rint((fx * x + skew * y) * inv_z + cx)
        v = np.rint(fy * y * inv_z + cy)
        if not (0 <= u < width and 0 <= v < height):
            continue
        p = int(v) * width + int(u)
        dm = depth[p]
        if dm > 0 and abs(z - dm) <= band_m:
            sel[m] = i
            pix[m] = p
            dist[m] = np.sqrt(x * x + y * y + z * z)
            m += 1
    return m


@compiled
def incidence_cosines(depth, width, height, fx, fy, cx, cy, pix, offset, smooth_ratio, out):
    """Cosine of the incidence angle (float32, may exceed 1 by round-off) at each flat pixel
    ``pix`` (n,) into ``out`` (n,); see ``frame_geometry.incidence_angles`` for the geometry
    (which takes the arccos with numpy: numba's differs in the last bit). depth (H * W,)
    float32 metres."""
    f32 = np.float32
    inv_off, half, ratio = f32(1.0 / offset), f32(0.5), f32(smooth_ratio)
    fx32, fy32 = f32(fx), f32(fy)
    for i in range(pix.shape[0]):
        p = pix[i]
        u, v = p % width, p // width
        z = depth[p]
        zu = zv = f32(0)
        for axis in range(2):
            coord, size, step = (u, width, offset) if axis == 0 else (v, height, offset * width)
            zp = depth[p + step] if coord + offset < size else f32(0)
            zm = depth[p - step] if coord >= offset else f32(0)
            ok_p, ok_m = zp > 0, zm > 0
            dp, dm = zp - z, z - zm
            adp, adm = abs(dp), abs(dm)
            if ok_p and (not ok_m or adp <= adm):
                g = dp
            elif ok_m:
                g = dm
            else:
                g = f32(0)
            if ok_p and ok_m and abs(dp - dm) <= ratio * max(adp, adm):
                g = half * (dp + dm)
            g = g * inv_off
            if axis == 0:
                zu = g
            else:
                zv = g
        du, dv = f32(u - cx), f32(v - cy)
        nz = du * zu + dv * zv + z
        a, b, c, d = fx32 * zu, fy32 * zv, du / fx32, dv / fy32
        n2 = a * a + b * b + nz * nz
        r2 = c * c + d * d + f32(1)
        out[i] = z / max(np.sqrt(n2 * r2), _F32_TINY)


@compiled
def gather_rows(logits, pix, out):
    """Copy rows ``pix`` (n,) of ``logits`` (H * W, K) into ``out`` (n, K); returns whether every
    copied value is finite (one pass over the rows the map reads, not the whole image)."""
    finite = True
    for i in range(pix.shape[0]):
        src, dst = logits[pix[i]], out[i]
        for c in range(src.shape[0]):
            dst[c] = src[c]
        for c in range(src.shape[0]):
            finite &= np.isfinite(dst[c])
    return finite


@compiled
def accumulate(acc, flat, z, log_p, p, weight, cell, lut, cells_per_class, off_a, off_b, b_votes, off_w, off_n):
    """Add observations to the voxels' accumulators ``acc`` (voxels, C) float32 in place.

    Observation i (of n) goes to voxel row ``flat[i]`` (< 0: skipped), with scaled logits
    ``z[i]`` (n, K), Laplace-smoothed log-probabilities ``log_p[i]`` and probabilities ``p[i]``
    (each (n, K) float32; only read for the accumulators that need them). Its sample weight is
    ``weight[i]`` times, when ``lut`` is non-empty, ``lut[argmax z[i] * cells_per_class +
    cell[i]]`` (the clamped GLFS table, flat). Increments, as ``fusion``'s strategies: A += w
    log_p at channels ``off_a``..+K, B += w p (w onehot(argmax z) when ``b_votes``) at
    ``off_b``..+K, W += w at ``off_w`` (an offset < 0: no such accumulator), and the
    observation count += 1 at ``off_n``."""
    n, k = z.shape
    # pass 1: each observation's weight (and vote); pass 2: the scatter, free of that serial
    # arg-max chain so that the voxel rows' cache misses overlap (~30 % faster at n = 6k)
    w = weight.copy()
    top = np.zeros(n, np.int64)
    if lut.shape[0] or (off_b >= 0 and b_votes):
        for i in range(n):
            zi = z[i]
            t, best = 0, zi[0]
            for c in range(1, k):   # the first maximum, as torch's argmax; branch-free
                better = zi[c] > best
                t = c if better else t
                best = zi[c] if better else best
            top[i] = t
            if lut.shape[0]:
                w[i] = lut[t * cells_per_class + cell[i]] * weight[i]
    for i in range(n):
        if flat[i] < 0:
            continue
        row, wi = acc[flat[i]], w[i]
        if off_a >= 0:
            a, lp = row[off_a:off_a + k], log_p[i]
            for c in range(k):
                a[c] += wi * lp[c]
        if off_b >= 0:
            if b_votes:
                row[off_b + top[i]] += wi
            else:
                b, pi = row[off_b:off_b + k], p[i]
                for c in range(k):
                    b[c] += wi * pi[c]
        if off_w >= 0:
            row[off_w] += wi
        row[off_n] += np.float32(1)
