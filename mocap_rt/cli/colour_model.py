"""``mocap-rt colour-model fit``: fit a parametric colour model (seed digest A.1) to labelled pixels."""

from __future__ import annotations

import argparse
import glob
from pathlib import Path


def register(subparsers) -> None:
    p = subparsers.add_parser("colour-model", help="fit/inspect parametric colour models (skin, shoes)",
                              description=__doc__)
    sub = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    fit = sub.add_parser("fit", help="fit a model from images+masks and/or the UCI skin pixel table")
    fit.add_argument("--images", nargs="*", default=[], help="images (or globs); BGR as read by OpenCV")
    fit.add_argument("--masks", nargs="*", default=[],
                     help="masks (or globs), one per image in the same order; nonzero = colour pixel")
    fit.add_argument("--uci", type=Path, help="UCI Skin_NonSkin.txt table (B G R label, 1 = skin)")
    fit.add_argument("--name", default="skin", help="model name stored in the file (default skin)")
    fit.add_argument("--accept", type=float, default=0.97,
                     help="fraction of training pixels the threshold accepts (default 0.97)")
    fit.add_argument("--out", type=Path, required=True, help="output TOML")
    fit.set_defaults(func=run)
    show = sub.add_parser("eval", help="acceptance of a model on the UCI table (skin vs non-skin)")
    show.add_argument("model", type=Path)
    show.add_argument("--uci", type=Path, required=True)
    show.set_defaults(func=run_eval)


def _expand(patterns: list[str]) -> list[str]:
    out = []
    for pat in patterns:
        hits = sorted(glob.glob(pat))
        if not hits:
            raise FileNotFoundError(f"no file matches {pat!r}")
        out.extend(hits)
    return out


def run(args: argparse.Namespace) -> int:
    import cv2
    import numpy as np

    from mocap_rt.perception.colour_model import (fit_colour_model, pixels_from_masks, read_uci_skin_table,
                                                  save_colour_model)

    images, masks = _expand(args.images), _expand(args.masks)
    if len(images) != len(masks):
        raise ValueError(f"--images gives {len(images)} files but --masks gives {len(masks)}")
    if not images and args.uci is None:
        raise ValueError("give --images/--masks and/or --uci")
    parts = []
    if images:
        imgs, msks = [], []
        for ip, mp in zip(images, masks):
            img = cv2.imread(ip, cv2.IMREAD_COLOR)
            msk = cv2.imread(mp, cv2.IMREAD_GRAYSCALE)
            if img is None:
                raise ValueError(f"cannot read image {ip}")
            if msk is None:
                raise ValueError(f"cannot read mask {mp}")
            imgs.append(img)
            msks.append(msk)
        parts.append(pixels_from_masks(imgs, msks))
    if args.uci is not None:
        rgb, is_skin = read_uci_skin_table(args.uci)
        parts.append(rgb[is_skin])
    pixels = np.concatenate(parts)
    model = fit_colour_model(pixels, args.name, args.accept)
    save_colour_model(model, args.out)
    print(f"{args.out}: {args.name} model from {len(pixels)} pixels; "
          f"sigma={model.sigma2 ** 0.5:.4f} max_error={model.max_error:.2e} grey {model.grey_min:.0f}..{model.grey_max:.0f}")
    return 0


def run_eval(args: argparse.Namespace) -> int:
    from mocap_rt.perception.colour_model import load_colour_model, read_uci_skin_table

    model = load_colour_model(args.model)
    rgb, is_skin = read_uci_skin_table(args.uci)
    p = model.likelihood_rgb(rgb)
    accepted = p >= model.min_likelihood
    print(f"{args.model}: accepts {accepted[is_skin].mean():.1%} of {is_skin.sum()} skin pixels and "
          f"{accepted[~is_skin].mean():.1%} of {(~is_skin).sum()} non-skin pixels")
    return 0
