"""Numba kernels of the blob stage's region steps (seed digest A.2 support): statistics of
connected skin regions (``colour_regions``, in ``cv2.connectedComponents``' label order), the
region snap of nearby blobs and the candidates for re-acquiring a lost blob.

Coordinates as in ``blob_kernels``; each kernel is tested against the NumPy/OpenCV code it
replaced in ``tests/perception``.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def colour_regions(skin, x0, y0, x1, y1):  # pragma: no cover - numba
    """8-connected regions of the colour pixels (>= 0.5) of ``skin[y0:y1, x0:x1]`` (h, w): what
    ``cv2.connectedComponents`` and a pass over its labels gave, from the pixel runs of the
    rows (union-find), without a label image (~3x faster on a person box's sparse map).

    Returns (n_labels, stats (n_labels, 7) int64): row 0 the background (w, h, -1, -1, 0, 0, 0),
    rows 1.. the regions in ``cv2.connectedComponents``' label order, which is the raster
    order of each region's first 2 x 2 block (OpenCV labels blocks of 2 x 2 pixels; the tests
    check the order against it); columns x_min, y_min, x_max, y_max, area, sum x, sum y in
    pixels of the window (top-left (x0, y0)).
    """
    h = y1 - y0
    w = x1 - x0
    cap = h * ((w + 1) // 2) + 1           # runs: at most one per two pixels of a row
    ry = np.empty(cap, np.int64)
    ra = np.empty(cap, np.int64)
    rb = np.empty(cap, np.int64)
    parent = np.empty(cap, np.int64)
    n = 0
    prev0 = 0
    prev1 = 0
    for y in range(h):
        row = skin[y0 + y, x0:x1]
        cur0 = n
        p = prev0
        x = 0
        while x < w:
            if row[x] < 0.5:
                x += 1
                continue
            a = x
            while x < w and row[x] >= 0.5:
                x += 1
            b = x - 1
            ry[n] = y
            ra[n] = a
            rb[n] = b
            parent[n] = n
            # union with the runs of the row above that touch [a - 1, b + 1] (8-connected)
            while p < prev1 and rb[p] < a - 1:
                p += 1
            q = p
            while q < prev1 and ra[q] <= b + 1:
                rq = q
                while parent[rq] != rq:
                    rq = parent[rq]
                rn = n
                while parent[rn] != rn:
                    rn = parent[rn]
                if rq < rn:
                    parent[rn] = rq
                elif rn < rq:
                    parent[rq] = rn
                q += 1
            n += 1
        prev0 = cur0
        prev1 = n
    comp = np.full(n, -1, np.int64)
    acc = np.empty((n, 8), np.int64)
    n_comp = 0
    bw = w // 2 + 1                          # first 2 x 2 block (row, col) -> row * bw + col
    for r in range(n):
        root = r
        while parent[root] != root:
            root = parent[root]
        parent[r] = root
        c = comp[root]
        key = (ry[r] // 2) * bw + ra[r] // 2
        ln = rb[r] - ra[r] + 1
        if c < 0:
            c = n_comp
            comp[root] = c
            n_comp += 1
            acc[c, 0] = ra[r]
            acc[c, 1] = ry[r]
            acc[c, 2] = rb[r]
            acc[c, 3] = ry[r]
            acc[c, 4] = 0
            acc[c, 5] = 0
            acc[c, 6] = 0
            acc[c, 7] = key
        acc[c, 0] = min(acc[c, 0], ra[r])
        acc[c, 1] = min(acc[c, 1], ry[r])
        acc[c, 2] = max(acc[c, 2], rb[r])
        acc[c, 3] = max(acc[c, 3], ry[r])
        acc[c, 4] += ln
        acc[c, 5] += (ra[r] + rb[r]) * ln // 2
        acc[c, 6] += ry[r] * ln
        acc[c, 7] = min(acc[c, 7], key)
    order = np.argsort(acc[:n_comp, 7])
    stats = np.empty((n_comp + 1, 7), np.int64)
    stats[0, 0] = w
    stats[0, 1] = h
    stats[0, 2] = -1
    stats[0, 3] = -1
    stats[0, 4] = 0
    stats[0, 5] = 0
    stats[0, 6] = 0
    for i in range(n_comp):
        for j in range(7):
            stats[i + 1, j] = acc[order[i], j]
    return n_comp + 1, stats


@numba.njit(cache=True, nogil=True)
def snap_window(centers, gate, x0, y0, x1, y1, near_gates, window_gates):  # pragma: no cover - numba
    """Window (wx0, wy0, wx1, wy1) ROI px in which ``snap_regions`` looks for the blobs'
    regions, or an empty one (wx1 <= wx0) when no snap is needed: fewer than two predicted
    blobs, or none nearer another than ``near_gates`` x their two gates. The window spans
    the predicted centres + ``window_gates`` x the largest gate, clipped to the box.
    """
    K = centers.shape[0]
    n_have = 0
    g_max = 0.0
    lox = 1e300
    loy = 1e300
    hix = -1e300
    hiy = -1e300
    any_near = False
    for i in range(K):
        if not (math.isfinite(centers[i, 0]) and math.isfinite(centers[i, 1])):
            continue
        n_have += 1
        g_max = max(g_max, gate[i])
        lox = min(lox, centers[i, 0])
        loy = min(loy, centers[i, 1])
        hix = max(hix, centers[i, 0])
        hiy = max(hiy, centers[i, 1])
        for j in range(K):
            if j != i and math.isfinite(centers[j, 0]) and math.isfinite(centers[j, 1]):
                dx = centers[i, 0] - centers[j, 0]
                dy = centers[i, 1] - centers[j, 1]
                if dx * dx + dy * dy < (near_gates * (gate[i] + gate[j])) ** 2:
                    any_near = True
    if n_have < 2 or not any_near:
        return 0, 0, 0, 0
    reach = window_gates * g_max
    wx0 = max(x0, int(lox - reach))
    wy0 = max(y0, int(loy - reach))
    wx1 = min(x1, int(hix + reach) + 1)
    wy1 = min(y1, int(hiy + reach) + 1)
    if wx1 - wx0 < 2 or wy1 - wy0 < 2:
        return 0, 0, 0, 0
    return wx0, wy0, wx1, wy1


@numba.njit(cache=True, nogil=True)
def snap_regions(stats, n_labels, wx0, wy0, centers, gate, min_area, max_regions, out):  # pragma: no cover
    """Labelling centres moved onto the blobs' own colour regions (``track_kernels.snap_centres``).

    stats (n_labels, 7): ``colour_regions`` of the window whose top-left is (wx0, wy0) ROI px.
    Regions of >= ``min_area`` pixels that a predicted blob (``centers`` (K, 2) ROI
    px, NaN = none) reaches (distance <= its gate + half the region's larger side) are
    candidates, at most ``max_regions`` (nearest first); the one-to-one assignment of
    candidates to the predicted blobs with the least total distance moves each blob's row
    of ``out`` (K, 2) to its region's centroid. Returns False (``out`` untouched) when
    there are fewer candidates than predicted blobs or no assignment is within reach.
    """
    K = centers.shape[0]
    ks = np.empty(K, np.int64)
    nk = 0
    for k in range(K):
        if math.isfinite(centers[k, 0]) and math.isfinite(centers[k, 1]):
            ks[nk] = k
            nk += 1
    n_big = 0
    for r in range(1, n_labels):
        if stats[r, 4] >= min_area:
            n_big += 1
    if n_big < nk:
        return False
    # candidates: regions some blob reaches, in label order
    cand_xy = np.empty((n_big, 2))
    cand_d = np.empty((n_big, nk))
    cand_reach = np.empty((n_big, nk), np.bool_)
    n_cand = 0
    for r in range(1, n_labels):
        area = stats[r, 4]
        if area < min_area:
            continue
        cx = stats[r, 5] / area + wx0
        cy = stats[r, 6] / area + wy0
        half = 0.5 * max(stats[r, 2] - stats[r, 0] + 1, stats[r, 3] - stats[r, 1] + 1)
        reached = False
        for i in range(nk):
            dx = centers[ks[i], 0] - cx
            dy = centers[ks[i], 1] - cy
            d = math.sqrt(dx * dx + dy * dy)
            cand_d[n_cand, i] = d
            cand_reach[n_cand, i] = d <= gate[ks[i]] + half
            reached |= cand_reach[n_cand, i]
        if reached:
            cand_xy[n_cand, 0] = cx
            cand_xy[n_cand, 1] = cy
            n_cand += 1
    if n_cand < nk:
        return False
    # at most max_regions candidates, nearest (to any blob) first; stable insertion sort
    order = np.arange(n_cand)
    if n_cand > max_regions:
        near = np.empty(n_cand)
        for c in range(n_cand):
            near[c] = cand_d[c, 0]
            for i in range(1, nk):
                near[c] = min(near[c], cand_d[c, i])
        for a in range(1, n_cand):
            b = a
            while b > 0 and near[order[b - 1]] > near[order[b]]:
                order[b - 1], order[b] = order[b], order[b - 1]
                b -= 1
        n_cand = max_regions
    # every assignment of distinct candidates to the nk blobs, in lexicographic order
    pick = np.zeros(nk, np.int64)
    best = np.full(nk, -1, np.int64)
    best_cost = np.inf
    while True:
        distinct = True
        for i in range(nk):
            for j in range(i):
                if pick[i] == pick[j]:
                    distinct = False
        if distinct:
            cost = 0.0
            ok = True
            for i in range(nk):
                c = order[pick[i]]
                if not cand_reach[c, i]:
                    ok = False
                    break
                cost += cand_d[c, i]
            if ok and cost < best_cost:
                best_cost = cost
                best[:] = pick
        i = nk - 1
        while i >= 0 and pick[i] == n_cand - 1:
            pick[i] = 0
            i -= 1
        if i < 0:
            break
        pick[i] += 1
    if best[0] < 0:
        return False
    for i in range(nk):
        c = order[best[i]]
        out[ks[i], 0] = cand_xy[c, 0]
        out[ks[i], 1] = cand_xy[c, 1]
    return True


@numba.njit(cache=True, nogil=True)
def acquire_candidates(stats, n_labels, x0, y0, sums, found, min_area, cand):  # pragma: no cover - numba
    """Unclaimed colour regions for re-acquisition (``BlobTracker._acquire``), largest first.

    stats (n_labels, 7): ``colour_regions`` of the box whose top-left is (x0, y0) ROI px. A
    region of >= ``min_area`` pixels is a candidate unless its box (+1 px) holds the
    centre of a found blob (``found`` (K,) bool, moments ``sums`` (K, 6)). cand (m, 4)
    receives (area, box centre x, box centre y ROI px, half the box's larger side + 1) of
    the m largest (ties in label order). Returns how many rows were written.
    """
    m = cand.shape[0]
    n = 0
    for r in range(1, n_labels):
        area = stats[r, 4]
        if area < min_area:
            continue
        xa = stats[r, 0]
        ya = stats[r, 1]
        xb = stats[r, 2]
        yb = stats[r, 3]
        claimed = False
        for k in range(found.shape[0]):
            if found[k]:
                mx = sums[k, 1] / sums[k, 0]
                my = sums[k, 2] / sums[k, 0]
                if x0 + xa - 1 <= mx <= x0 + xb + 1 and y0 + ya - 1 <= my <= y0 + yb + 1:
                    claimed = True
        if claimed:
            continue
        # insert by area, after equal areas; drop what falls off the end
        i = min(n, m - 1)
        if n == m and area <= cand[m - 1, 0]:
            continue
        while i > 0 and cand[i - 1, 0] < area:
            cand[i] = cand[i - 1]
            i -= 1
        cand[i, 0] = area
        cand[i, 1] = x0 + 0.5 * (xa + xb)
        cand[i, 2] = y0 + 0.5 * (ya + yb)
        cand[i, 3] = 0.5 * max(xb - xa, yb - ya) + 1.0
        n = min(n + 1, m)
    return n


@numba.njit(cache=True, nogil=True)
def acquire_regions(skin, x0, y0, x1, y1, sums, found, min_area, cand):  # pragma: no cover - numba
    """``colour_regions`` of the box [x0, x1) x [y0, y1) and their ``acquire_candidates``, in
    one call (a lost blob runs them every frame). Returns how many rows of cand were written."""
    n, stats = colour_regions(skin, x0, y0, x1, y1)
    if n <= 1:
        return 0
    return acquire_candidates(stats, n, x0, y0, sums, found, min_area, cand)
