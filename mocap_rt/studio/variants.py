"""Variants of a BVH clip and the motion registry of ``mocap-rt synth``.

* ``time_reversed``: frames in reverse order (a walk becomes a walk backwards).
* ``mirrored``: the mirror image in the file's x = 0 plane (x -> -x; in the world frame
  too, since the Y-up -> Z-up map keeps x). Left and right joints swap names, offsets are
  mirrored, rotations ``R -> M R M`` (M = diag(-1, 1, 1): X angles kept, Y and Z negated)
  and x positions negated, so the result is a physically valid mirrored motion whose FK
  equals the mirror image of the original with left and right swapped.
* ``turned``: the body turned about the vertical axis by ``rate * t`` (deg/s): each
  frame's pose is rotated about the body's centre (mean of the joints), and the centre's
  horizontal path is rebuilt from the original's steps turned by the same angle, so a
  walk curves (turning while moving) and an in-place motion turns on the spot.

Registry: ``load_motion("procedural:NAME[:SEED]" | "CLIP.bvh", variant)`` with variant
``reversed``, ``mirrored`` or ``turn:DEG_PER_S`` (several joined by ``+``).
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from mocap_rt.io.bvh import BvhClip, BvhJoint, BvhSkeleton, joint_transforms, read_bvh
from mocap_rt.studio.body_map import find_map

_SWAPS = ((r"Left", "Right"), (r"Right", "Left"), (r"_L$", "_R"), (r"_R$", "_L"), (r"\.l$", ".r"),
          (r"\.r$", ".l"), (r"^L(?=[A-Z])", "R"), (r"^R(?=[A-Z])", "L"), (r"^l", "r"), (r"^r", "l"))


def mirror_name(name: str, names: set[str]) -> str:
    """The name of the other side's joint (``LeftArm`` <-> ``RightArm``, ``Foot_L`` <->
    ``Foot_R``, ``LThumb`` <-> ``RThumb``, ``lhand`` <-> ``rhand``), or ``name`` itself for a
    joint on the midline (no counterpart in ``names``)."""
    for pat, rep in _SWAPS:
        other = re.sub(pat, rep, name)
        if other != name and other in names:
            return other
    return name


def time_reversed(clip: BvhClip) -> BvhClip:
    """The clip played backwards: frame i is the original's frame n - 1 - i."""
    return replace(clip, motion=clip.motion[::-1].copy())


def mirrored(clip: BvhClip) -> BvhClip:
    """The clip mirrored in the file's x = 0 plane, left and right swapped (module doc)."""
    skel = clip.skeleton
    names = set(skel.names)
    new_names = [mirror_name(n, names) for n in skel.names]
    if len(set(new_names)) != len(new_names):
        raise ValueError(f"mirrored: left/right joint names do not pair up: {new_names}")
    flip = np.array([-1.0, 1.0, 1.0])
    joints = tuple(BvhJoint(nn, j.parent, j.offset * flip, j.channels,
                            None if j.end_site is None else j.end_site * flip)
                   for nn, j in zip(new_names, skel.joints))
    sign = np.ones(skel.n_channels)
    for j, s in zip(skel.joints, skel.channel_starts):
        for k, ch in enumerate(j.channels):
            if ch in ("Yrotation", "Zrotation", "Xposition"):
                sign[s + k] = -1.0
    return BvhClip(BvhSkeleton(joints), clip.motion * sign, clip.frame_time_s)


def turned(clip: BvhClip, rate_deg_s: float) -> BvhClip:
    """The clip turned about the vertical axis by ``rate_deg_s * t`` (module doc)."""
    skel = clip.skeleton
    root = skel.joints[0]
    pos_ch = [c for c in root.channels if c.endswith("position")]
    if len(pos_ch) != 3:
        raise ValueError("turned: the root joint needs three position channels")
    up = "XYZ".index(find_map(skel.names).up)
    rots, pos = joint_transforms(skel, clip.motion)
    F = clip.n_frames
    angle = np.radians(rate_deg_s) * np.arange(F) * clip.frame_time_s
    axis = np.zeros(3)
    axis[up] = 1.0
    turn = Rotation.from_rotvec(angle[:, None] * axis).as_matrix()          # (F, 3, 3)
    centre = pos.mean(axis=1)                                              # (F, 3)
    steps = np.diff(centre, axis=0)
    new_centre = centre.copy()
    new_centre[1:] = centre[0] + np.cumsum(np.einsum("fij,fj->fi", turn[:-1], steps), axis=0)
    new_centre[:, up] = centre[:, up]
    new_root_pos = new_centre + np.einsum("fij,fj->fi", turn, pos[:, 0] - centre)
    new_root_rot = turn @ rots[:, 0]
    motion = clip.motion.copy()
    s = int(skel.channel_starts[0])
    rot_cols = [s + k for k, c in enumerate(root.channels) if c.endswith("rotation")]
    seq = "".join(c[0] for c in root.channels if c.endswith("rotation")).upper()
    import warnings

    with warnings.catch_warnings():          # gimbal lock: the rotation is still exact
        warnings.simplefilter("ignore", UserWarning)
        motion[:, rot_cols] = np.unwrap(Rotation.from_matrix(new_root_rot).as_euler(seq, degrees=True),
                                        period=360.0, axis=0)
    for k, c in enumerate(root.channels):
        if c.endswith("position"):
            motion[:, s + k] = new_root_pos[:, "XYZ".index(c[0])]
    return BvhClip(skel, motion, clip.frame_time_s)


VARIANTS = ("reversed", "mirrored", "turn:DEG_PER_S")


def apply_variant(clip: BvhClip, variant: str | None) -> BvhClip:
    """``variant``: None, ``reversed``, ``mirrored``, ``turn:DEG_PER_S`` or several joined by ``+``."""
    for v in (variant or "").split("+"):
        v = v.strip()
        if not v:
            continue
        if v == "reversed":
            clip = time_reversed(clip)
        elif v == "mirrored":
            clip = mirrored(clip)
        elif v.startswith("turn:"):
            try:
                rate = float(v[5:])
            except ValueError:
                raise ValueError(f"variant {v!r}: turn rate must be a number (deg/s)") from None
            clip = turned(clip, rate)
        else:
            raise ValueError(f"unknown variant {v!r}; known: {', '.join(VARIANTS)} (join with '+')")
    return clip


def load_motion(spec: str | Path, variant: str | None = None) -> tuple[BvhClip, str]:
    """A clip from a motion spec, with a variant applied; returns (clip, name).

    spec : a BVH path, or ``procedural:NAME[:SEED]`` (``mocap_rt.studio.procedural_motions.MOTIONS``).
    The name is the file name or ``procedural_NAME_sSEED``, plus ``_VARIANT`` when given.
    """
    spec = str(spec)
    if spec.startswith("procedural:"):
        from mocap_rt.studio.procedural_motions import generate

        parts = spec.split(":")
        if len(parts) not in (2, 3) or not parts[1]:
            raise ValueError(f"motion {spec!r}: expected procedural:NAME[:SEED]")
        try:
            seed = int(parts[2]) if len(parts) == 3 else 0
        except ValueError:
            raise ValueError(f"motion {spec!r}: the seed must be an integer") from None
        clip, name = generate(parts[1], seed), f"procedural_{parts[1]}_s{seed}"
    else:
        path = Path(spec)
        if not path.is_file():
            raise FileNotFoundError(f"motion: no such BVH file {path}")
        clip, name = read_bvh(path), path.stem
    if variant:
        name += "_" + re.sub(r"[^A-Za-z0-9.-]+", "_", variant)
    return apply_variant(clip, variant), name
