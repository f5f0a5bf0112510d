"""Synthetic scenes with exact truth for the perception tests.

A textured background; a person drawn with OpenCV: trunk and limbs in clothing colours,
head and hands in a skin colour from the UCI table's typical skin, shoes in the studio's
shoe colour; a shadow (background darkened by a factor) beside the person; optional
global flicker. Returns the image, the truth mask and the truth blob centres.

A module of its own (not conftest.py): the tests import it by a name no other test directory has.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

SKIN_RGB = np.array([224, 172, 140])        # a typical light skin tone (R, G, B)
SHOE_RGB = np.array([46, 158, 38])          # the studio's green shoes (R, G, B)
SHIRT_BGR = (150, 90, 40)                   # blue shirt
TROUSERS_BGR = (90, 40, 75)                 # dark purple trousers


@dataclass
class Scene:
    image: np.ndarray        # (H, W, 3) uint8 BGR
    background: np.ndarray   # (B, H, W, 3) uint8 BGR
    mask: np.ndarray         # (H, W) bool truth silhouette
    centres: dict            # cue name -> (x, y) truth centre of the drawn blob


def shade(rgb: np.ndarray, grey: float) -> tuple[int, int, int]:
    """BGR tuple of colour ``rgb`` rescaled to mean grey level ``grey``."""
    c = np.clip(rgb * grey / rgb.mean(), 0, 255)
    return int(c[2]), int(c[1]), int(c[0])


@functools.lru_cache(maxsize=8)
def make_background(size=(640, 480), n=5, seed=0, noise=2.0) -> np.ndarray:
    """(n, H, W, 3) uint8 BGR empty-scene frames (cached: do not modify)."""
    w, h = size
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    base = np.stack([110 + 40 * xx / w, 140 + 30 * yy / h, 150 + 20 * np.sin(xx / 37.0)], axis=2)
    base[yy > 0.7 * h] = (90, 110, 120)                       # floor
    texture = rng.normal(0, 6, (h // 8 + 1, w // 8 + 1, 3)).repeat(8, 0).repeat(8, 1)[:h, :w]
    base = base + texture
    out = np.clip(base[None] + rng.normal(0, noise, (n, h, w, 3)), 0, 255).astype(np.uint8)
    out.flags.writeable = False
    return out


def draw_person(canvas: np.ndarray, mask: np.ndarray, centres: dict, *, cx: float, scale: float = 1.0,
                hand_l=None, hand_r=None, skin_grey=165.0, shoe_grey=80.0) -> None:
    """Draw a frontal stick person centred at x=cx (the person faces the camera)."""
    s = scale
    top = 60 * s
    def E(img, c, axes, col):
        cv2.ellipse(img, (int(round(c[0] * 16)), int(round(c[1] * 16))), (int(round(axes[0] * 16)), int(round(axes[1] * 16))),
                    0, 0, 360, col, -1, cv2.LINE_8, 4)
    def L(img, a, b, t, col):
        cv2.line(img, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), col, int(t))
    head = (cx, top + 25 * s)
    neck = (cx, top + 55 * s)
    pelvis = (cx, top + 190 * s)
    hand_l = hand_l or (cx + 95 * s, top + 140 * s)      # person's left = image right
    hand_r = hand_r or (cx - 95 * s, top + 140 * s)
    foot_l = (cx + 30 * s, top + 345 * s)
    foot_r = (cx - 30 * s, top + 345 * s)
    for img, colours in ((canvas, None), (mask, 255)):
        col = lambda c: colours if colours is not None else c
        L(img, (cx + 28 * s, pelvis[1]), (foot_l[0], foot_l[1] - 10 * s), 22 * s, col(TROUSERS_BGR))
        L(img, (cx - 28 * s, pelvis[1]), (foot_r[0], foot_r[1] - 10 * s), 22 * s, col(TROUSERS_BGR))
        L(img, (cx + 40 * s, neck[1] + 10 * s), hand_l, 14 * s, col(SHIRT_BGR))
        L(img, (cx - 40 * s, neck[1] + 10 * s), hand_r, 14 * s, col(SHIRT_BGR))
        E(img, (cx, top + 120 * s), (48 * s, 78 * s), col(SHIRT_BGR))
        L(img, head, neck, 16 * s, col(SHIRT_BGR))
        E(img, head, (20 * s, 25 * s), col(shade(SKIN_RGB, skin_grey)))
        E(img, hand_l, (10 * s, 12 * s), col(shade(SKIN_RGB, skin_grey)))
        E(img, hand_r, (10 * s, 12 * s), col(shade(SKIN_RGB, skin_grey)))
        E(img, foot_l, (16 * s, 9 * s), col(shade(SHOE_RGB, shoe_grey)))
        E(img, foot_r, (16 * s, 9 * s), col(shade(SHOE_RGB, shoe_grey)))
    centres.update(head=head, hand_l=hand_l, hand_r=hand_r, foot_l=foot_l, foot_r=foot_r)


def make_scene(size=(640, 480), cx=320.0, seed=1, shadow=0.55, flicker=1.0, **person) -> Scene:
    bg = make_background(size, seed=seed)
    w, h = size
    rng = np.random.default_rng(seed + 100)
    img = bg[0].astype(np.float32)
    # shadow on the floor beside the person
    sh = np.zeros((h, w), np.uint8)
    cv2.ellipse(sh, (int(cx + 90), int(0.86 * h)), (110, 25), 0, 0, 360, 255, -1)
    img[sh > 0] *= shadow
    img *= flicker
    canvas = np.clip(img, 0, 255).astype(np.uint8)
    mask = np.zeros((h, w), np.uint8)
    centres: dict = {}
    draw_person(canvas, mask, centres, cx=cx, **person)
    noisy = np.clip(canvas + rng.normal(0, 2.0, canvas.shape), 0, 255).astype(np.uint8)
    return Scene(noisy, bg, mask > 0, centres)

