"""The person's silhouette and colour maps in one pass over the person's box.

After the component search (``background.change_mask`` + ``largest_component_filled``),
two per-pixel stages remain: the boundary clean-up of the silhouette (boundary pixels stay
only when strongly changed, ``background.keep_strong_boundary``: MJPG colour bleeding
makes the plain change mask ~1 px too wide) and the skin/shoe maps on the silhouette's
pixels (seed digest A.1, eq. 1-2, ``colour_model.colour_maps_binary``). ``silhouette_colour``
does both in one pass, the colour test through a per-grey-level table of the two models'
chromaticities (``colour_model.chroma_table``). Results are identical to the two stages.
Coordinates: image pixels unless a name says otherwise.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def _chroma_boxes(table, emax_a, emax_b):  # pragma: no cover - numba
    """The chromaticity box (r lo, r hi, g lo, g hi, float32) of each model's accepted pixels:
    its table's (R/S, G/S) over the grey levels it holds, widened by the error radius
    sqrt(emax) and 1e-6 (rounding). A pixel outside both boxes fails both tests; an empty box
    (lo > hi) for a model that holds no grey level."""
    lim = np.empty(8)
    for m in range(2):
        lim[4 * m] = lim[4 * m + 2] = np.inf
        lim[4 * m + 1] = lim[4 * m + 3] = -np.inf
    for si in range(1, table.shape[0]):
        valid = np.int64(table[si, 4])
        for m in range(2):
            if valid & (m + 1):
                lim[4 * m] = min(lim[4 * m], table[si, 2 * m])
                lim[4 * m + 1] = max(lim[4 * m + 1], table[si, 2 * m])
                lim[4 * m + 2] = min(lim[4 * m + 2], table[si, 2 * m + 1])
                lim[4 * m + 3] = max(lim[4 * m + 3], table[si, 2 * m + 1])
    r_a = np.sqrt(emax_a) + 1e-6
    r_b = np.sqrt(emax_b) + 1e-6
    return (np.float32(lim[0] - r_a), np.float32(lim[1] + r_a), np.float32(lim[2] - r_a), np.float32(lim[3] + r_a),
            np.float32(lim[4] - r_b), np.float32(lim[5] + r_b), np.float32(lim[6] - r_b), np.float32(lim[7] + r_b))


@numba.njit(cache=True, nogil=True)
def silhouette_colour_kernel(member, change, img, x0, y0, table, emax_a, emax_b, sil, map_a, map_b):  # pragma: no cover
    """Silhouette and two colour maps of a box in one pass.

    member (h, w) uint8: > 0 = in the filled component; change (h, w) uint8 change codes
    (255 = strongly changed); the box's top-left is image pixel (x0, y0) of img (H, W, 3)
    uint8 BGR (C-contiguous). A pixel is silhouette when in the component and either
    interior (its four neighbours are in it; border replicated) or strongly changed:
    exactly ``background.keep_strong_boundary``. Silhouette pixels get the colour test of
    two models (``colour_model.chroma_table``, thresholds ``emax_a``, ``emax_b``): exactly
    ``colour_model.colour_maps_binary``. Outputs (h, w): sil uint8 {0, 255}, map_a / map_b
    uint8 {0, 1} (a quarter of float32's memory traffic; the blob stage takes them as they are).
    Returns the silhouette's pixel count.

    Row by row, each step a branch-free loop the compiler vectorises: the silhouette row,
    then (rows with silhouette only) the normalised chromaticities ``r / s``, ``g / s``
    (float32, as ``colour_model.colour_bits`` divides) of the whole row, then the table test on the
    silhouette pixels, written out here (through an inlined helper function numba's code was
    2.4x slower). 640x480 person box, one core: ~0.15 ms against ~0.25 ms for one branchy loop.
    The table test runs only on the silhouette pixels inside a model's chromaticity box
    (``_chroma_boxes``), marked in the chromaticity loop: ~15 % of the person's pixels on the
    studio clips (clothes are neither skin nor shoe), 89 -> 81 us.
    """
    h, w = member.shape
    W = img.shape[1]
    flat = img.reshape(-1)
    rn_row = np.empty(w, np.float32)
    gn_row = np.empty(w, np.float32)
    si_row = np.empty(w, np.int32)
    cand = np.empty(w, np.uint8)
    ra0, ra1, ga0, ga1, rb0, rb1, gb0, gb1 = _chroma_boxes(table, emax_a, emax_b)
    n_total = 0
    for y in range(h):
        m = member[y]
        up = member[max(y - 1, 0)]
        dn = member[min(y + 1, h - 1)]
        ch = change[y]
        s_row = sil[y]
        a_row = map_a[y]
        b_row = map_b[y]
        n_sil = 0
        for x in range(1, w - 1):
            inside = (m[x] != 0) & (((m[x - 1] != 0) & (m[x + 1] != 0) & (up[x] != 0) & (dn[x] != 0))
                                    | (ch[x] == 255))
            s_row[x] = np.uint8(255) * np.uint8(inside)
            n_sil += np.int64(inside)
        for e in range(min(w, 2)):                    # the row's ends, border replicated (once if w = 1)
            x = e * (w - 1)
            inside = (m[x] != 0) & (((m[max(x - 1, 0)] != 0) & (m[min(x + 1, w - 1)] != 0) & (up[x] != 0)
                                     & (dn[x] != 0)) | (ch[x] == 255))
            s_row[x] = np.uint8(255) * np.uint8(inside)
            n_sil += np.int64(inside)
        a_row[:] = 0
        b_row[:] = 0
        if n_sil == 0:
            continue
        n_total += n_sil
        px = flat[3 * ((y0 + y) * W + x0):3 * ((y0 + y) * W + x0 + w)]
        n_cand = 0
        for x in range(w):
            si = np.int32(px[3 * x]) + np.int32(px[3 * x + 1]) + np.int32(px[3 * x + 2])
            s = np.float32(max(si, 1))
            rn = np.float32(px[3 * x + 2]) / s
            gn = np.float32(px[3 * x + 1]) / s
            rn_row[x] = rn
            gn_row[x] = gn
            si_row[x] = si
            c = (s_row[x] != 0) & (((rn >= ra0) & (rn <= ra1) & (gn >= ga0) & (gn <= ga1))
                                   | ((rn >= rb0) & (rn <= rb1) & (gn >= gb0) & (gn <= gb1)))
            cand[x] = np.uint8(c)
            n_cand += np.int64(c)
        if n_cand == 0:
            continue
        for x in range(w):
            si = si_row[x]
            if cand[x] == 0 or si == 0:
                continue
            valid = np.int64(table[si, 4])           # bit 0: model a's grey range holds si / 3, 1: b's
            if valid & 1:
                dr = rn_row[x] - table[si, 0]
                dg = gn_row[x] - table[si, 1]
                if dr * dr + dg * dg <= emax_a:
                    a_row[x] = 1
            if valid & 2:
                dr = rn_row[x] - table[si, 2]
                dg = gn_row[x] - table[si, 3]
                if dr * dr + dg * dg <= emax_b:
                    b_row[x] = 1
    return n_total


@numba.njit(cache=True, nogil=True)
def top_point(sil):  # pragma: no cover - numba
    """The silhouette's top (x, y) in box pixels, for the head's acquisition: the mean x of
    the first row's person pixels (the box's middle if none), 6 % of the box's height below it."""
    h, w = sil.shape
    n = 0
    sx = 0.0
    for x in range(w):
        if sil[0, x] != 0:
            n += 1
            sx += x
    return (sx / n if n else w / 2.0), 0.06 * h


def silhouette_colour(member: np.ndarray, change: np.ndarray, img: np.ndarray, box: tuple[int, int, int, int],
                      table: np.ndarray, emax_a: float, emax_b: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(sil (h, w) uint8 {0, 255}, map_a, map_b (h, w) uint8 {0, 1}, the silhouette's pixel
    count) of the person box (``silhouette_colour_kernel``); member / change (h, w) uint8 over
    the box."""
    h, w = member.shape
    sil = np.empty((h, w), np.uint8)
    map_a = np.empty((h, w), np.uint8)
    map_b = np.empty((h, w), np.uint8)
    n = silhouette_colour_kernel(member, change, img, box[0], box[1], table, emax_a, emax_b, sil, map_a, map_b)
    return sil, map_a, map_b, n


@numba.njit(cache=True, nogil=True)
def half_cells(sil, step):  # pragma: no cover - numba
    """Cells of ``step`` x ``step`` pixels of ``sil`` (bh, bw) uint8 (nonzero = person) that are
    at least half the person's: (ceil(bh / step), ceil(bw / step)) bool; pixels past the box's
    edge count as background. ``cues.CompactSilhouette.from_box_mask``'s cells (its area mean
    >= 0.5), by counting: identical for steps 2-5, the steps of boxes up to 640 x 480.

    Row of cells by row of cells: the person pixels of its ``step`` rows counted per column in
    uint8 (a unit-stride loop the compiler vectorises; at most ``step`` per column), then each
    cell's ``step`` columns, the pairs of step 2 (the 640x480 person box's) without a loop
    (10 -> 6 us on a 640x480 person box; 14 us adding each row's pixels to the cells with a stride)."""
    bh, bw = sil.shape
    h, w = -(-bh // step), -(-bw // step)
    out = np.empty((h, w), np.bool_)
    col = np.zeros(w * step, np.uint8)       # per column of the row of cells, zero-padded to whole cells
    for i in range(h):
        col[:] = 0
        for y in range(i * step, min((i + 1) * step, bh)):
            row = sil[y]
            for x in range(bw):
                col[x] += np.uint8(row[x] != 0)
        o = out[i]
        if step == 2:
            for k in range(w):
                o[k] = col[2 * k] + col[2 * k + 1] >= 2
        else:
            for k in range(w):
                c = 0
                for d in range(step):
                    c += col[k * step + d]
                o[k] = 2 * c >= step * step
    return out
