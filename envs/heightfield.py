"""Recast's solid heightfield, compiled: rasterise a triangle mesh into spans, merge them per
column, and Recast's three span filters (``rcRasterizeTriangles``, ``rcAddSpan``,
``rcFilterLowHangingWalkableObstacles``, ``rcFilterLedgeSpans``,
``rcFilterWalkableLowHeightSpans``).

Conventions: world z-up metres. The grid covers the xy bounds from ``origin`` = (x0, y0, z0)
(the mesh's lower corner): column (row, col) spans x in [x0 + col cs, x0 + (col + 1) cs), y
likewise with ``row``; its index is ``row * w + col``. Heights are integer units of ``ch``
above z0: a span [smin, smax] is solid from smin to smax; smin = floor(z_lo / ch), smax =
ceil(z_hi / ch), at least smin + 1, as Recast snaps them. ``area`` is 1 on a walkable span
(its top-most surface is walkable), 0 otherwise.

Spans come out in CSR form: ``start`` (h * w + 1,) int64, the spans of column c are
``start[c]:start[c + 1]``, sorted bottom to top, never touching each other. ``ztop`` (float64)
is the exact (unquantised) height of each span's top, metres (the floor height an agent standing
on it has).
"""
from __future__ import annotations

import math

import numpy as np

from calnav.common.jit import compiled

MAX_HEIGHT = 0xFFFF          # Recast's "open to the sky" height, units
_POLY_CAP = 12               # vertices of a triangle clipped to a cell (at most 7)


@compiled
def _divide(src, n, out1, out2, x, axis):
    """Split polygon ``src[:n]`` (xyz rows) by the line coordinate[axis] = x: ``out1`` gets the
    part with coordinate <= x, ``out2`` the part >= x (points on the line go to both, as in
    Recast's ``dividePoly``). Returns (n1, n2)."""
    d = np.empty(_POLY_CAP)
    for i in range(n):
        d[i] = x - src[i, axis]
    m = 0
    k = 0
    j = n - 1
    for i in range(n):
        ina = d[j] >= 0
        inb = d[i] >= 0
        if ina != inb:
            s = d[j] / (d[j] - d[i])
            for c in range(3):
                out1[m, c] = src[j, c] + (src[i, c] - src[j, c]) * s
                out2[k, c] = out1[m, c]
            m += 1
            k += 1
            if d[i] > 0:
                out1[m, :] = src[i, :]
                m += 1
            elif d[i] < 0:
                out2[k, :] = src[i, :]
                k += 1
        else:
            if d[i] >= 0:
                out1[m, :] = src[i, :]
                m += 1
                if d[i] != 0:
                    j = i
                    continue
            out2[k, :] = src[i, :]
            k += 1
        j = i
    return m, k


@compiled
def _cell_bounds(tris, origin, cs, w, h):
    """(F, 4) int64 inclusive [row0, row1, col0, col1] of each triangle's bounding box (clamped),
    and the total cell count (an upper bound on the fragments)."""
    f = tris.shape[0]
    out = np.empty((f, 4), np.int64)
    total = 0
    for t in range(f):
        lo_x = min(tris[t, 0, 0], tris[t, 1, 0], tris[t, 2, 0])
        hi_x = max(tris[t, 0, 0], tris[t, 1, 0], tris[t, 2, 0])
        lo_y = min(tris[t, 0, 1], tris[t, 1, 1], tris[t, 2, 1])
        hi_y = max(tris[t, 0, 1], tris[t, 1, 1], tris[t, 2, 1])
        r0 = min(max(int(math.floor((lo_y - origin[1]) / cs)), 0), h - 1)
        r1 = min(max(int(math.floor((hi_y - origin[1]) / cs)), 0), h - 1)
        c0 = min(max(int(math.floor((lo_x - origin[0]) / cs)), 0), w - 1)
        c1 = min(max(int(math.floor((hi_x - origin[0]) / cs)), 0), w - 1)
        out[t, 0], out[t, 1], out[t, 2], out[t, 3] = r0, r1, c0, c1
        total += (r1 - r0 + 1) * (c1 - c0 + 1)
    return out, total


@compiled
def rasterise(tris, walkable, origin, cs, ch, w, h, zrange):
    """Every triangle's footprint in every cell it overlaps (the triangle clipped to the cell,
    Recast's conservative rasterisation: a thin leg or a wall face on a cell border marks its
    cells). tris: (F, 3, 3) float64; walkable: (F,) bool. Returns fragment arrays (column
    index int64, smin int32, smax int32, area uint8, exact top float64 metres)."""
    bounds, cap = _cell_bounds(tris, origin, cs, w, h)
    col = np.empty(cap, np.int64)
    smin_o = np.empty(cap, np.int32)
    smax_o = np.empty(cap, np.int32)
    area_o = np.empty(cap, np.uint8)
    ztop_o = np.empty(cap, np.float64)
    buf_in = np.empty((_POLY_CAP, 3))
    buf_rest = np.empty((_POLY_CAP, 3))
    row_poly = np.empty((_POLY_CAP, 3))
    row_rest = np.empty((_POLY_CAP, 3))
    cell_poly = np.empty((_POLY_CAP, 3))
    n_out = 0
    for t in range(tris.shape[0]):
        r0, r1, c0, c1 = bounds[t, 0], bounds[t, 1], bounds[t, 2], bounds[t, 3]
        nin = 3
        for i in range(3):
            buf_in[i, :] = tris[t, i, :]
        for r in range(r0, r1 + 1):
            y_hi = origin[1] + (r + 1) * cs
            if r == h - 1:            # the last row takes everything left (the mesh's max y)
                y_hi = np.inf
            nrow, nrest = _divide(buf_in, nin, row_poly, buf_rest, y_hi, 1)
            buf_in, buf_rest = buf_rest, buf_in
            nin = nrest
            if nrow < 3:
                continue
            ncur = nrow
            for c in range(c0, c1 + 1):
                x_hi = origin[0] + (c + 1) * cs
                if c == w - 1:
                    x_hi = np.inf
                ncell, nleft = _divide(row_poly, ncur, cell_poly, row_rest, x_hi, 0)
                row_poly, row_rest = row_rest, row_poly
                ncur = nleft
                if ncell < 3:
                    continue
                lo = cell_poly[0, 2]
                hi = cell_poly[0, 2]
                for i in range(1, ncell):
                    lo = min(lo, cell_poly[i, 2])
                    hi = max(hi, cell_poly[i, 2])
                lo -= origin[2]
                hi -= origin[2]
                if hi < 0.0 or lo > zrange:
                    continue
                lo = max(lo, 0.0)
                hi = min(hi, zrange)
                ilo = min(max(int(math.floor(lo / ch)), 0), MAX_HEIGHT)
                ihi = min(max(int(math.ceil(hi / ch)), ilo + 1), MAX_HEIGHT)
                col[n_out] = r * w + c
                smin_o[n_out] = ilo
                smax_o[n_out] = ihi
                area_o[n_out] = 1 if walkable[t] else 0
                ztop_o[n_out] = hi + origin[2]
                n_out += 1
    return col[:n_out], smin_o[:n_out], smax_o[:n_out], area_o[:n_out], ztop_o[:n_out]


@compiled
def merge_spans(col, smin, smax, area, ztop, n_cols, merge_thr):
    """Fragments sorted by (column, smin) -> CSR spans. Touching or overlapping fragments of a
    column merge into one span; its area is walkable when a walkable fragment's top lies within
    ``merge_thr`` units of the merged top (Recast's flag merge, made independent of the order
    the triangles come in). Returns (start, smin, smax, area, ztop)."""
    n = col.shape[0]
    s_lo = np.empty(n, np.int32)
    s_hi = np.empty(n, np.int32)
    s_area = np.empty(n, np.uint8)
    s_top = np.empty(n, np.float64)
    start = np.zeros(n_cols + 1, np.int64)
    m = 0
    i = 0
    while i < n:
        c = col[i]
        top = smax[i]
        j = i + 1
        while j < n and col[j] == c and smin[j] <= top:
            top = max(top, smax[j])
            j += 1
        a = 0
        z = -np.inf
        for k in range(i, j):
            if smax[k] >= top - merge_thr and area[k] > a:
                a = area[k]
            z = max(z, ztop[k])
        s_lo[m] = smin[i]
        s_hi[m] = top
        s_area[m] = a
        s_top[m] = z
        start[c + 1] += 1
        m += 1
        i = j
    for c in range(n_cols):
        start[c + 1] += start[c]
    return start, s_lo[:m], s_hi[:m], s_area[:m], s_top[:m]


@compiled
def filter_low_hanging(start, smax, area, climb):
    """A non-walkable span right above a walkable one whose top is within ``climb`` units of
    the walkable top becomes walkable (curbs, steps, a low box: the agent steps onto them).
    In place."""
    for c in range(start.shape[0] - 1):
        prev_walkable = False
        prev_area = 0
        prev_top = 0
        for s in range(start[c], start[c + 1]):
            walkable = area[s] != 0
            if not walkable and prev_walkable and abs(int(smax[s]) - prev_top) <= climb:
                area[s] = prev_area
            prev_walkable = walkable   # the original flag: a stack of boxes does not chain up
            prev_area = area[s]
            prev_top = int(smax[s])


@compiled
def filter_ledges(start, smin, smax, area, w, h, walk_height, climb):
    """A walkable span with a drop of more than ``climb`` to any 4-neighbour it could step to
    (a hole, the grid border, a table edge) or whose reachable neighbours differ by more than
    ``climb`` (a steep slope) is not walkable. Reads geometry only, so the result does not
    depend on the order. In place."""
    out = area.copy()
    for r in range(h):
        for c in range(w):
            cell = r * w + c
            for s in range(start[cell], start[cell + 1]):
                if area[s] == 0:
                    continue
                bot = int(smax[s])
                top = int(smin[s + 1]) if s + 1 < start[cell + 1] else MAX_HEIGHT
                lowest = MAX_HEIGHT
                acc_lo = bot
                acc_hi = bot
                for d in range(4):
                    rr = r + (0, 1, 0, -1)[d]
                    cc = c + (-1, 0, 1, 0)[d]
                    if rr < 0 or rr >= h or cc < 0 or cc >= w:
                        lowest = min(lowest, -climb - bot)
                        continue
                    ncell = rr * w + cc
                    n0 = start[ncell]
                    n1 = start[ncell + 1]
                    # the open space below the neighbour's first span counts as a floor at -climb
                    ntop = int(smin[n0]) if n1 > n0 else MAX_HEIGHT
                    if min(top, ntop) - max(bot, -climb) > walk_height:
                        lowest = min(lowest, -climb - bot)
                    for ns in range(n0, n1):
                        nbot = int(smax[ns])
                        ntop = int(smin[ns + 1]) if ns + 1 < n1 else MAX_HEIGHT
                        if min(top, ntop) - max(bot, nbot) > walk_height:
                            lowest = min(lowest, nbot - bot)
                            if abs(nbot - bot) <= climb:
                                acc_lo = min(acc_lo, nbot)
                                acc_hi = max(acc_hi, nbot)
                if lowest < -climb or acc_hi - acc_lo > climb:
                    out[s] = 0
    area[:] = out


@compiled
def filter_low_height(start, smin, smax, area, walk_height):
    """A walkable span with less than ``walk_height`` units of open space above it (under a
    table, inside a wall, below a shelf) is not walkable. In place."""
    for c in range(start.shape[0] - 1):
        for s in range(start[c], start[c + 1]):
            top = int(smin[s + 1]) if s + 1 < start[c + 1] else MAX_HEIGHT
            if top - int(smax[s]) < walk_height:
                area[s] = 0


@compiled
def connections(start, smin, smax, area, w, h, walk_height, climb):
    """(S, 4) int64: for each walkable span, the walkable span it connects to in each 4-neighbour
    column (-1 for none): open space of at least ``walk_height`` units shared with it and a
    floor step of at most ``climb`` units (Recast's compact-heightfield links). Directions
    (d_row, d_col): (0, -1), (1, 0), (0, 1), (-1, 0)."""
    n = smin.shape[0]
    con = np.full((n, 4), -1, np.int64)
    for r in range(h):
        for c in range(w):
            cell = r * w + c
            for s in range(start[cell], start[cell + 1]):
                if area[s] == 0:
                    continue
                bot = int(smax[s])
                top = int(smin[s + 1]) if s + 1 < start[cell + 1] else MAX_HEIGHT
                for d in range(4):
                    rr = r + (0, 1, 0, -1)[d]
                    cc = c + (-1, 0, 1, 0)[d]
                    if rr < 0 or rr >= h or cc < 0 or cc >= w:
                        continue
                    ncell = rr * w + cc
                    n1 = start[ncell + 1]
                    for ns in range(start[ncell], n1):
                        if area[ns] == 0:
                            continue
                        nbot = int(smax[ns])
                        ntop = int(smin[ns + 1]) if ns + 1 < n1 else MAX_HEIGHT
                        if min(top, ntop) - max(bot, nbot) >= walk_height and abs(nbot - bot) <= climb:
                            con[s, d] = ns
                            break
    return con


@compiled
def find_root(parent, a):
    """Union-find: the root of ``a``'s set in ``parent`` ((N,) int64), halving the path as it
    goes (each visited node skips to its grandparent), so later finds are shorter. In place."""
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@compiled
def components(con, area):
    """(S,) int64 label of each walkable span's connected surface (union-find over ``con``;
    -1 for spans that are not walkable), labels 0..k-1 in order of first appearance."""
    n = con.shape[0]
    parent = np.arange(n)
    for s in range(n):
        if area[s] == 0:
            continue
        for d in range(4):
            t = con[s, d]
            if t < 0:
                continue
            a = find_root(parent, s)
            b = find_root(parent, t)
            if a != b:
                parent[max(a, b)] = min(a, b)
    label = np.full(n, -1, np.int64)
    root_label = np.full(n, -1, np.int64)
    k = 0
    for s in range(n):
        if area[s] == 0:
            continue
        a = s
        while parent[a] != a:
            a = parent[a]
        if root_label[a] < 0:
            root_label[a] = k
            k += 1
        label[s] = root_label[a]
    return label
