"""Procedural motions and clip variants: each checked on FK / the studio's body map."""

import numpy as np
import pytest

from mocap_rt.body.skeleton import J, body_model
from mocap_rt.fusion.evaluate import anatomical_angles, trunk_axes
from mocap_rt.io.bvh import forward_kinematics, read_bvh
from mocap_rt.names import JOINT_NAMES
from mocap_rt.studio.body_map import BONES, body_motion
from mocap_rt.studio.procedural_motions import MOTIONS, generate
from mocap_rt.studio.variants import apply_variant, load_motion, mirror_name, mirrored, time_reversed, turned

FPS = 30.0
CLIPS = ("cmu/cmu_02_01_walk.bvh", "cmu/cmu_131_01_start_walk_stop.bvh", "bandai_namco/dataset-1_walk_normal_001.bvh")


def _short(data_dir, rel, n=60):
    clip = read_bvh(data_dir / "bvh" / rel)
    return type(clip)(clip.skeleton, clip.motion[:n], clip.frame_time_s)


@pytest.mark.parametrize("rel", CLIPS)
def test_mirrored_is_the_mirror_image_with_sides_swapped(data_dir, rel):
    clip = _short(data_dir, rel)
    mir = mirrored(clip)
    names = set(clip.skeleton.names)
    p = forward_kinematics(clip.skeleton, clip.motion, include_end_sites=True)
    q = forward_kinematics(mir.skeleton, mir.motion, include_end_sites=True)
    qn = mir.skeleton.names + mir.skeleton.end_site_names
    pn = clip.skeleton.names + clip.skeleton.end_site_names
    swapped = [qn.index(mirror_name(n.removesuffix("_end"), names) + ("_end" if n.endswith("_end") else ""))
               for n in pn]
    np.testing.assert_allclose(q[:, swapped] * [-1.0, 1.0, 1.0], p, atol=1e-9)
    assert sum(mirror_name(n, names) != n for n in names) >= 16
    # world: the subject's left side is still on its left (a proper mirror, not a relabelling)
    jm = body_motion(mir, placement="none").joints
    fwd, left, up = trunk_axes(jm)
    lat = jm[:, J["hand_l"]] - jm[:, J["hand_r"]]
    assert np.median(np.sum(lat * left, -1)) > 0.1


def test_reversed_frame_i_is_original_frame_n_minus_1_minus_i(data_dir):
    clip = _short(data_dir, CLIPS[0])
    rev = time_reversed(clip)
    p, q = forward_kinematics(clip.skeleton, clip.motion), forward_kinematics(rev.skeleton, rev.motion)
    n = clip.n_frames
    for i in (0, 7, n - 1):
        np.testing.assert_array_equal(q[i], p[n - 1 - i])


@pytest.mark.parametrize("rel", CLIPS[:2])
def test_turned_rotates_each_pose_by_the_ramp(data_dir, rel):
    clip = _short(data_dir, rel)
    rate = 45.0
    tc = turned(clip, rate)
    p = forward_kinematics(clip.skeleton, clip.motion)
    q = forward_kinematics(tc.skeleton, tc.motion)
    ang = np.radians(rate) * np.arange(clip.n_frames) * clip.frame_time_s
    c, s = np.cos(ang), np.sin(ang)

    def rot(v, k):  # rotation about the file's up axis (+Y) by ang[k]: (x, z) -> (c x + s z, -s x + c z)
        ck, sk = c[k].reshape(-1, *([1] * (v.ndim - 2))), s[k].reshape(-1, *([1] * (v.ndim - 2)))
        return np.stack([ck * v[..., 0] + sk * v[..., 2], v[..., 1], -sk * v[..., 0] + ck * v[..., 2]], -1)

    frames = np.arange(clip.n_frames)
    pc, qc = p.mean(axis=1, keepdims=True), q.mean(axis=1, keepdims=True)
    np.testing.assert_allclose(q - qc, rot(p - pc, frames), atol=1e-6)       # each pose turned
    np.testing.assert_allclose(np.diff(qc[:, 0], axis=0), rot(np.diff(pc[:, 0], axis=0), frames[:-1]),
                               atol=1e-6)                                      # each step turned
    np.testing.assert_allclose(q[0], p[0], atol=1e-9)
    assert np.degrees(ang[-1]) > 20                                            # and it did turn


def test_registry_spec_and_variant_errors(data_dir):
    clip, name = load_motion("procedural:clap:3", "mirrored+reversed")
    assert name == "procedural_clap_s3_mirrored_reversed" and clip.n_frames > 100
    with pytest.raises(ValueError, match="unknown procedural motion"):
        load_motion("procedural:nope")
    with pytest.raises(ValueError, match="seed must be an integer"):
        load_motion("procedural:clap:x")
    with pytest.raises(ValueError, match="unknown variant"):
        apply_variant(clip, "sideways")
    with pytest.raises(ValueError, match="turn rate"):
        apply_variant(clip, "turn:fast")
    with pytest.raises(FileNotFoundError, match="no such BVH"):
        load_motion(data_dir / "missing.bvh")


# ----------------------------------------------------------------------------- procedural clips

_CACHE: dict = {}


def _joints(name: str, seed: int = 0) -> np.ndarray:
    """(F, P, 3) body points of the clip through the studio's map, world, floor kept."""
    if (name, seed) not in _CACHE:
        _CACHE[name, seed] = body_motion(generate(name, seed, fps=FPS), placement="none")
    return _CACHE[name, seed]


def _limits_deg():
    lim = np.degrees(body_model().limits)
    return {"knee": -lim[J["knee_r"], 0, 0], "elbow": lim[J["elbow_r"], 0, 1],
            "hip_flex": lim[J["hip_r"], 0], "hip_abd": lim[J["hip_r"], 1]}


@pytest.mark.parametrize("name", sorted(MOTIONS))
def test_procedural_clip_is_a_valid_body_motion(data_dir, name):
    bm = _joints(name)
    pts, jts = bm.points, bm.joints
    assert np.isfinite(pts).all() and pts.shape[0] == int(6 * FPS) + 1
    feet = [bm.point(n)[:, 2] for n in ("toe_l", "toe_r", "heel_l", "heel_r")]
    assert min(f.min() for f in feet) > -0.03                       # never through the floor
    assert np.median(np.min(feet, axis=0)) < 0.03                   # and standing on it
    # rigid bones (the trunk bends over three spine joints; the map's foot point moves with
    # the ankle angle, so those two are not rigid by construction)
    rigid = [(x, y) for x, y in BONES if "torso" not in (x, y) and not y.startswith("foot")]
    a = np.array([JOINT_NAMES.index(x) for x, _ in rigid])
    b = np.array([JOINT_NAMES.index(y) for _, y in rigid])
    length = np.linalg.norm(jts[:, a] - jts[:, b], axis=-1)
    assert len(rigid) == 15 and np.ptp(length, axis=0).max() < 1e-6
    ang, lim, tol = anatomical_angles(jts), _limits_deg(), 3.0
    for s in ("l", "r"):
        assert ang[f"knee_flex_{s}"].max() <= lim["knee"] + tol
        assert ang[f"elbow_flex_{s}"].max() <= lim["elbow"] + tol
        assert lim["hip_flex"][0] - tol <= ang[f"hip_flex_{s}"].min()
        assert ang[f"hip_flex_{s}"].max() <= lim["hip_flex"][1] + tol
        assert lim["hip_abd"][0] - tol <= ang[f"hip_abd_{s}"].min()
        assert ang[f"hip_abd_{s}"].max() <= lim["hip_abd"][1] + tol
    # smooth: no joint faster than 6 m/s (the elbow of a folding arm, the arm swing of a jump), no flip
    assert np.linalg.norm(np.diff(jts, axis=0), axis=-1).max() < 0.2


def test_seeds_vary_the_clip_and_are_deterministic():
    a, b, c = _joints("clap", 0).joints, _joints("clap", 1).joints, body_motion(generate("clap", 0, fps=FPS)).joints
    assert np.abs(a - b).max() > 0.05
    np.testing.assert_array_equal(body_motion(generate("clap", 0, fps=FPS)).joints, c)


def _pt(name, seed, p):
    return _joints(name, seed).point(p)


def _dist(name, seed, p, q):
    return np.linalg.norm(_pt(name, seed, p) - _pt(name, seed, q), axis=-1)


@pytest.mark.parametrize("seed", [0, 11])
def test_each_clip_does_what_it_is_named_for(seed):
    # clap: the hand centres meet (capsule radius 4 cm) and part again, many times
    d = _dist("clap", seed, "hand_l", "hand_r")
    assert d.min() < 0.07 and d.max() > 0.25
    assert np.sum((d[1:] < 0.08) & (d[:-1] >= 0.08)) >= 5
    # arms overhead: both hands above the head
    up = lambda n, p: _pt(n, seed, p)[:, 2] - _pt(n, seed, "head")[:, 2]  # noqa: E731
    assert (np.minimum(up("arms_overhead", "hand_l"), up("arms_overhead", "hand_r")) > 0.15).sum() > 10
    # hands on head: close to the head and above it for seconds
    on = (_dist("hands_on_head", seed, "hand_l", "head") < 0.2) & (_dist("hands_on_head", seed, "hand_r", "head") < 0.2)
    assert on.sum() > 2 * FPS and (up("hands_on_head", "hand_l")[on] > 0.05).all()
    # hand behind the head: one hand near the head and behind it (trunk frame)
    jb = _joints("hand_behind_head", seed).joints
    fwd = trunk_axes(jb)[0]
    behind = [(np.sum((jb[:, J[h]] - jb[:, J["head"]]) * fwd, -1) < -0.05)
              & (_dist("hand_behind_head", seed, h, "head") < 0.2) for h in ("hand_l", "hand_r")]
    assert max(x.sum() for x in behind) > 2 * FPS
    # hands cross in front of the face: left hand right of the right hand, both near the face
    jc = _joints("hands_cross_face", seed).joints
    fwd, left, _ = trunk_axes(jc)
    crossed = np.sum((jc[:, J["hand_l"]] - jc[:, J["hand_r"]]) * left, -1) < -0.1
    front = [(np.sum((jc[:, J[h]] - jc[:, J["head"]]) * fwd, -1) > 0.1) & (_dist("hands_cross_face", seed, h, "head") < 0.4)
             for h in ("hand_l", "hand_r")]
    assert (crossed & front[0] & front[1]).sum() > 10
    # jump: both feet off the floor together by > 10 cm
    low = np.minimum(_pt("jump", seed, "foot_l")[:, 2], _pt("jump", seed, "foot_r")[:, 2])
    assert low.max() - np.median(low) > 0.10
    # crouch: the pelvis goes down by > 25 cm; with hands to feet the hands come near the feet
    pz = _pt("crouch", seed, "pelvis")[:, 2]
    assert pz.max() - pz.min() > 0.25
    assert _dist("crouch_hands_to_feet", seed, "hand_l", "foot_l").min() < 0.33
    # feet cross: the left foot right of the right foot (and the other way) with both feet down
    jf = _joints("feet_cross", seed).joints
    lat = np.sum((jf[:, J["foot_l"]] - jf[:, J["foot_r"]]) * trunk_axes(jf)[1], -1)
    down = np.maximum(jf[:, J["foot_l"], 2], jf[:, J["foot_r"], 2]) < np.min(jf[:, [J["foot_l"], J["foot_r"]], 2]) + 0.03
    assert ((lat < -0.03) & down).sum() > 5 and lat.max() > 0.1
    # turn in place and jumping jacks: the heading turns, the pelvis stays / drifts
    for name, min_turn, max_travel in (("turn_in_place", 300, 0.3), ("jumping_jacks", 100, 1.5)):
        fwd = trunk_axes(_joints(name, seed).joints)[0]
        heading = np.unwrap(np.arctan2(fwd[:, 1], fwd[:, 0]))
        assert np.degrees(np.ptp(heading)) > min_turn
        pel = _pt(name, seed, "pelvis")[:, :2]
        assert np.linalg.norm(pel - pel[0], axis=-1).max() < max_travel
    # jumping jacks: hands above the head while the feet are apart
    jj = _joints("jumping_jacks", seed).joints
    apart = np.linalg.norm(jj[:, J["foot_l"]] - jj[:, J["foot_r"]], axis=-1) > 0.45
    high = np.minimum(jj[:, J["hand_l"], 2], jj[:, J["hand_r"], 2]) > jj[:, J["head"], 2]
    assert (apart & high).sum() > 10
    # sidestep: the pelvis travels sideways (along the hips' axis), not forwards
    js = _joints("sidestep", seed).joints
    v = js[-1, J["pelvis"]] - js[0, J["pelvis"]]
    path = js[:, J["pelvis"]] - js[0, J["pelvis"]]
    f0, l0, _ = trunk_axes(js[:1])
    assert np.abs(path @ l0[0]).max() > 0.4 and np.abs(path @ f0[0]).max() < 0.1 and np.isfinite(v).all()
