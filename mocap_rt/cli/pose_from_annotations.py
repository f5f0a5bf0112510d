"""``mocap-rt pose-from-annotations ANN.json --out DIR``: the thesis' two-view pipeline.

Two calibrated images with annotated end effectors and limb segments (see
``mocap_rt.body.annotations`` for the JSON format) -> 3D points and line directions ->
bone-length refit -> improved CCD -> skeleton. Writes ``DIR/pose.bvh`` (one frame) and
``DIR/pose.npz`` (``joints`` (1, J, 3) m world, ``joint_names``, ``refit_joints``,
``effectors`` (5, 3)).
"""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser("pose-from-annotations",
                              help="two-view pose from annotated end effectors and limb segments (thesis B.2-B.7)",
                              description=__doc__)
    p.add_argument("annotations", metavar="ANN.json", help="annotations file")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import numpy as np

    from mocap_rt.body.annotations import pose_from_annotations, read_annotations
    from mocap_rt.body.bvh_export import bvh_frame, bvh_skeleton
    from mocap_rt.body.skeleton import END_EFFECTORS
    from mocap_rt.io.bvh_writer import write_bvh
    from mocap_rt.names import JOINT_NAMES

    path = Path(args.annotations)
    if not path.is_file():
        raise FileNotFoundError(f"annotations file not found: {path}")
    res = pose_from_annotations(read_annotations(path))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_bvh(out / "pose.bvh", bvh_skeleton(res.model), bvh_frame(res.model, res.root_pos, res.ik.angles)[None],
              1.0 / 30.0)
    np.savez_compressed(out / "pose.npz", joints=res.joints[None], joint_names=np.array(JOINT_NAMES),
                        refit_joints=res.refit_joints, effectors=np.array([res.effectors[n] for n in END_EFFECTORS]),
                        effector_names=np.array(END_EFFECTORS))
    print(f"wrote {out / 'pose.bvh'} and {out / 'pose.npz'}")
    print(f"CCD: {res.ik.iterations} iterations; end effector errors after IK:")
    for n, p in zip(END_EFFECTORS, res.ik.position_error_m):
        print(f"  {n:7s} {p * 1e3:7.2f} mm")
    for n, p in zip(JOINT_NAMES, res.joints):
        print(f"  {n:11s} {p[0]:8.3f} {p[1]:8.3f} {p[2]:8.3f}")
    return 0
