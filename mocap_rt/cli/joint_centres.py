"""``mocap-rt joint-centres``: functional joint centres from a marker trial (C3D or TRC).

Writes one virtual marker per joint (named after the joint) to a TRC file and prints, per
joint, the method, the fit residual, the joint's range of motion in the trial and the
mean +- std of its distance to each neighbouring joint (bone lengths).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

METHOD_CHOICES = ("patent", "patent32", "patent31", "linear", "score", "sphere", "obrien")


def register(subparsers) -> None:
    p = subparsers.add_parser("joint-centres", help="functional joint centres from marker data (C3D/TRC)",
                              description=__doc__.splitlines()[0])
    p.add_argument("trial", type=Path, help="marker trial, .c3d or .trc")
    p.add_argument("--segments", type=Path, required=True,
                   help="segment definition TOML ([segments.NAME] markers, [joints.NAME] parent/child)")
    p.add_argument("--out", type=Path, required=True, help="output TRC with one marker per joint")
    p.add_argument("--method", choices=METHOD_CHOICES, default="patent",
                   help="patent (default): the patent's nonlinear objective from the 3+3 linear start, used "
                        "symmetrically; patent32/patent31: its one-sided 3+2/3+1 forms; linear: the 3+3 linear "
                        "solution; baselines: score, sphere, obrien")
    p.add_argument("--no-rigid", action="store_true", help="skip the rigid (Procrustes) preprocessing")
    p.add_argument("--similarity", action="store_true",
                   help="rigid preprocessing with a per-frame scale (the patent's similarity model)")
    p.add_argument("--with-markers", action="store_true", help="also copy the trial's markers into --out")
    p.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from mocap_rt.io.files import claim_outputs, refuse_input_as_output
    from mocap_rt.markers.io import MarkerData, read_markers, write_trc
    from mocap_rt.markers.segments import load_segments
    from mocap_rt.markers.trial import joint_centres_for_trial

    refuse_input_as_output(args.out, [args.trial, args.segments])
    claim_outputs([args.out], args.overwrite)
    t0 = time.perf_counter()
    data = read_markers(args.trial)
    segset = load_segments(args.segments)
    result = joint_centres_for_trial(data, segset, args.method, rigid=not args.no_rigid,
                                     similarity=args.similarity)
    out = result.as_marker_data(data)
    if args.with_markers:
        out = MarkerData(data.labels + out.labels, np.concatenate([data.positions, out.positions], axis=1),
                         data.rate_hz, data.first_frame)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_trc(args.out, out)
    elapsed = time.perf_counter() - t0

    bones = result.bone_lengths(segset)
    print(f"{args.trial}: {data.n_frames} frames @ {data.rate_hz:g} Hz, {len(data.labels)} markers; "
          f"method {args.method}, rigid preprocessing {'off' if args.no_rigid else 'on'}")
    print(f"{'joint':<12} {'method':<8} {'residual_mm':>11} {'rom_deg':>7}  neighbours: mean±std mm")
    for name in result.names:
        fit = result.fits.get(name)
        links = [b for b in bones if name in (b.joint_a, b.joint_b)]
        text = "  ".join(f"{b.joint_b if b.joint_a == name else b.joint_a} {b.mean_m * 1e3:.1f}±{b.std_m * 1e3:.2f}"
                         for b in links)
        if fit is None:
            print(f"{name:<12} {args.method:<8} {'failed':>11} {'':>7}  {text}")
            continue
        print(f"{name:<12} {fit.method:<8} {fit.residual_m * 1e3:11.2f} {result.rom_deg[name]:7.0f}  {text}")
    print(f"wrote {args.out} ({len(result.names)} joint markers) in {elapsed:.2f} s")
    return 0 if len(result.fits) == len(result.names) else 1
