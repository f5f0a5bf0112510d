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

from mocap_rt.perception.colour_model import colour_bits_table


@numba.njit(cache=True, nogil=True)
def silhouette_colour_kernel(member, change, img, x0, y0, table, emax_a, emax_b, sil, map_a, map_b):  # pragma: no cover
    """Silhouette and two colour maps of a box in one pass.

    member (h, w) uint8: > 0 = in the filled component; change (h, w) uint8 change codes
    (255 = strongly changed); the box's top-left is image pixel (x0, y0) of img (H, W, 3)
    uint8 BGR. A pixel is silhouette when in the component and either interior (its four
    neighbours are in it; border replicated) or strongly changed: exactly
    ``background.keep_strong_boundary``. Silhouette pixels get the colour test of two models
    (``colour_model.chroma_table``, thresholds ``emax_a``, ``emax_b``): exactly
    ``colour_model.colour_maps_binary``. Outputs (h, w): sil uint8 {0, 255}, map_a / map_b
    float32 {0, 1}.
    """
    h, w = member.shape
    for y in range(h):
        for x in range(w):
            map_a[y, x] = 0.0
            map_b[y, x] = 0.0
            sil[y, x] = 0
            if member[y, x] == 0:
                continue
            interior = ((x == 0 or member[y, x - 1] != 0) and (x == w - 1 or member[y, x + 1] != 0)
                        and (y == 0 or member[y - 1, x] != 0) and (y == h - 1 or member[y + 1, x] != 0))
            if not (interior or change[y, x] == 255):
                continue
            sil[y, x] = 255
            bits = colour_bits_table(img[y0 + y, x0 + x, 0], img[y0 + y, x0 + x, 1], img[y0 + y, x0 + x, 2],
                                     table, emax_a, emax_b)
            if bits & 1:
                map_a[y, x] = 1.0
            if bits & 2:
                map_b[y, x] = 1.0


def silhouette_colour(member: np.ndarray, change: np.ndarray, img: np.ndarray, box: tuple[int, int, int, int],
                      table: np.ndarray, emax_a: float, emax_b: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(sil (h, w) uint8 {0, 255}, map_a, map_b (h, w) float32) of the person box
    (``silhouette_colour_kernel``); member / change (h, w) uint8 over the box."""
    h, w = member.shape
    sil = np.empty((h, w), np.uint8)
    map_a = np.empty((h, w), np.float32)
    map_b = np.empty((h, w), np.float32)
    silhouette_colour_kernel(member, change, img, box[0], box[1], table, emax_a, emax_b, sil, map_a, map_b)
    return sil, map_a, map_b
