"""Where each leg meets its shoe: the heel end of the foot, measured in the image (seed
digest A.6, issue 10 item 4).

A shoe blob's long axis gives the foot's direction only modulo 180 deg: a body turned round
with its left and right exchanged puts the same blobs in the same places. What tells heel
from toe is the leg: the shank stands on the heel end of the shoe. In the image the leg's
silhouette leaves the shoe blob where the shank is, so the centroid of the person's pixels
in a ring around the blob, above its centre, is a measured point of the leg's attachment
(``leg_attachment``). Fusion compares it, along the shoe's axis, with the projection of its
body's ankle (``body.foot_axis``): in a side view the attachment sits at the heel end, in a
view along the foot it sits at whichever end the shank's projection covers, and the
comparison with the projected ankle handles both.

Measured on ten studio clips (12355 shoe blobs, 6 cameras, open loop), the attachment's
offset along the blob axis from the blob centre against the true ankle's: correlation 0.89,
median ratio 1.02, same sign in 93 % of the blobs; in the views where a foot turned round
would put its ankle on the other side, the truth's side in 87 % (docs/perception.md, "Where
the legs meet the shoes").

The ring is ``RING_SD`` standard deviations of the blob's own covariance (inside: the shoe;
outside: the rest of the body); pixels nearer the other shoe's centre than ``OTHER_SD`` of
this blob's minor standard deviation are left out (the other leg). Leaving out the other
blob's whole ellipse too (3 sds of its covariance) was measured and not kept (docs/body.md).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from mocap_rt.perception.blob_kernels import ellipse_frame

RING_SD = (2.2, 4.0)     # the ring around the shoe blob, in its standard deviations
OTHER_SD = 3.0           # pixels within this many minor sds of the other shoe's centre are its leg's
MIN_RING_PX = 3          # fewer leg pixels in the ring: no measurement
MIN_BLOB_AREA_PX = 20.0  # a smaller shoe blob has no axis to measure along (body.foot_axis uses it too)


@numba.njit(cache=True, nogil=True)
def leg_attachment(sil, x0, y0, xy, cov, area, min_area_px, out):  # pragma: no cover - numba
    """Leg attachment of each shoe blob.

    sil (h, w) uint8 silhouette of the person box whose top-left image pixel is (x0, y0)
    (> 0 = person); xy (2, 2) image px, cov (2, 2, 2) px^2, area (2,) px of the two shoe
    blobs (left, right; NaN / 0 = not found). Writes out (2, 2): the centroid (image px) of
    the silhouette pixels in the ring ``RING_SD`` around each blob and on or above its centre
    row, without those near the other blob (its leg, module doc); NaN where the blob is
    missing, smaller than ``min_area_px``, or fewer than ``MIN_RING_PX`` pixels are found.
    """
    h, w = sil.shape
    for k in range(2):
        out[k, 0] = np.nan
        out[k, 1] = np.nan
        cx = xy[k, 0] - x0
        cy = xy[k, 1] - y0
        if not (area[k] >= min_area_px and math.isfinite(cx) and math.isfinite(cy)
                and np.all(np.isfinite(cov[k]))):
            continue
        sd1, sd2, u, v = ellipse_frame(cov[k])
        ox = xy[1 - k, 0] - x0
        oy = xy[1 - k, 1] - y0
        other = math.isfinite(ox) and math.isfinite(oy)
        r_other2 = (OTHER_SD * sd2) ** 2
        lo2 = RING_SD[0] * RING_SD[0]
        hi2 = RING_SD[1] * RING_SD[1]
        reach_x = RING_SD[1] * math.sqrt(cov[k, 0, 0])     # the ring's bounding box
        reach_y = RING_SD[1] * math.sqrt(cov[k, 1, 1])
        xa = max(0, int(math.floor(cx - reach_x)))
        xb = min(w, int(math.ceil(cx + reach_x)) + 1)
        ya = max(0, int(math.floor(cy - reach_y)))
        yb = min(h, int(math.floor(cy)) + 1)             # above the centre only
        n = 0
        sx = 0.0
        sy = 0.0
        for y in range(ya, yb):
            dy = y - cy
            for x in range(xa, xb):
                if sil[y, x] == 0:
                    continue
                dx = x - cx
                ta = (dx * u + dy * v) / sd1
                tb = (-dx * v + dy * u) / sd2
                d2 = ta * ta + tb * tb
                if d2 < lo2 or d2 > hi2:
                    continue
                if other and (x - ox) ** 2 + (y - oy) ** 2 <= r_other2:
                    continue
                n += 1
                sx += dx
                sy += dy
        if n >= MIN_RING_PX:
            out[k, 0] = cx + sx / n + x0
            out[k, 1] = cy + sy / n + y0
