"""The capsule body, compact silhouettes, the chamfer cost and the pan/swivel fit."""

import numpy as np
import pytest

from mocap_rt.body import silhouette as S
from mocap_rt.body.analytic import body_axes
from mocap_rt.body.estimate import bone_lengths_from_joints
from mocap_rt.body import fit as Fm
from mocap_rt.body.fit import BodyFitter, FitConfig
from mocap_rt.body.kinematics import forward_kinematics
from mocap_rt.body.skeleton import J, BoneLengths, body_model
from mocap_rt.cues import SILHOUETTE_MAX_BYTES, CompactSilhouette
from mocap_rt.geometry.rig import ring_rig
from mocap_rt.io.bvh import read_bvh
from mocap_rt.names import CUE_JOINT_INDEX, JOINT_NAMES
from mocap_rt.studio.body_map import POINT_NAMES, body_motion
from mocap_rt.studio.body_shape import body_primitives
from mocap_rt.studio.render import RenderConfig, StudioRenderer
from studio_silhouettes import silhouette_cues


@pytest.fixture(scope="module")
def walk(data_dir):
    clip = read_bvh(data_dir / "bvh" / "cmu" / "cmu_02_01_walk.bvh")
    return body_motion(clip, fps=30, n_frames=40, placement="centre")


@pytest.fixture(scope="module")
def rendered(walk):
    """Frames 10 and 30 of the walk rendered by the studio into a 6-camera ring at 320x240:
    {frame: {camera: CameraCues with the compact silhouette}}."""
    rig = ring_rig(6, size=(320, 240))
    ren = StudioRenderer(rig, config=RenderConfig(noise_sigma_levels=0.0))
    return rig, {f: silhouette_cues(ren, body_primitives(walk.points[f]), f) for f in (10, 30)}


def test_capsules_are_the_studio_body(walk):
    A, B = np.empty((S.N_CAPSULES, 3)), np.empty((S.N_CAPSULES, 3))
    for f in (0, 17, 39):
        prims = body_primitives(walk.points[f])
        S.body_capsules(walk.points[f], A, B)
        assert prims.names == S.CAPSULE_NAMES
        np.testing.assert_allclose(A, prims.a, atol=1e-12)
        np.testing.assert_allclose(B, prims.b, atol=1e-12)
        np.testing.assert_array_equal(S.CAPSULE_RADII_M, prims.radius)


def test_model_shoe_lies_along_the_foot_centred_on_the_foot_joint():
    model = body_model(BoneLengths(), "paper")
    angles = np.zeros((len(JOINT_NAMES), 3))
    angles[0, 2] = np.radians(30.0)                 # the body turned 30 deg about Z
    pos, rot = forward_kinematics(model, np.array([0.2, -0.1, 1.0]), angles)
    pts = np.empty((len(POINT_NAMES), 3))
    S.pose_points(pos, rot, np.radians(model.lengths.foot_pitch_deg), pts)
    fwd = np.array([-np.sin(np.radians(30.0)), np.cos(np.radians(30.0)), 0.0])   # body +Y turned
    for s in ("l", "r"):
        toe, heel = pts[POINT_NAMES.index(f"toe_{s}")], pts[POINT_NAMES.index(f"heel_{s}")]
        np.testing.assert_allclose((toe + heel) / 2, pos[J[f"foot_{s}"]], atol=1e-12)
        np.testing.assert_allclose(toe - heel, 2 * S.SHOE_HALF_LENGTH_M * fwd, atol=1e-9)   # level, forward
        np.testing.assert_allclose(pts[POINT_NAMES.index(f"fingers_{s}")] - pos[J[f"hand_{s}"]],
                                   pos[J[f"hand_{s}"]] - pos[J[f"wrist_{s}"]], atol=1e-12)


@pytest.mark.parametrize("box", [(0, 0, 640, 480), (100, 37, 151, 333), (5, 9, 3, 2)])
def test_compact_silhouette_keeps_its_budget_and_round_trips(box):
    rng = np.random.default_rng(box[2])
    x, y, w, h = box
    yy, xx = np.mgrid[0:h, 0:w]
    sil = ((xx - w / 2) ** 2 / (w / 2.5) ** 2 + (yy - h / 2) ** 2 / (h / 2.2) ** 2 < 1).astype(np.uint8)
    sil[rng.random(sil.shape) < 0.01] ^= 1                       # salt and pepper
    c = CompactSilhouette.from_box_mask(sil * 255, box)
    assert c.nbytes <= SILHOUETTE_MAX_BYTES
    back = CompactSilhouette.from_dict(c.to_dict())
    assert (back.x0, back.y0, back.step) == (c.x0, c.y0, c.step)
    np.testing.assert_array_equal(back.mask, c.mask)
    full = np.zeros((480, 640), bool)
    full[y:y + h, x:x + w] = sil > 0
    rec = c.full_mask(640, 480)
    if sil.sum() > 100:                                            # the shape survives the downsampling
        assert (rec & full).sum() / (rec | full).sum() > 0.9


def test_the_true_body_fits_its_silhouettes_and_a_turned_one_does_not(walk, rendered):
    rig, frames = rendered
    A, B = np.empty((S.N_CAPSULES, 3)), np.empty((S.N_CAPSULES, 3))
    for f, cues in frames.items():
        T = S.SilhouetteTargets.from_cues(rig.cameras, cues)
        assert T.n_views == 6
        pts = walk.points[f]
        S.body_capsules(pts, A, B)
        good = S.capsules_cost(A, B, S.CAPSULE_RADII_M, *T.args())
        # the same body reflected front to back through the pelvis (hands and feet move too)
        pelvis = pts[POINT_NAMES.index("pelvis")]
        fwd = pts[POINT_NAMES.index("toe_r")] - pts[POINT_NAMES.index("heel_r")]
        fwd[2] = 0
        fwd /= np.linalg.norm(fwd)
        S.body_capsules(pts - 2 * np.outer((pts - pelvis) @ fwd, fwd), A, B)
        bad = S.capsules_cost(A, B, S.CAPSULE_RADII_M, *T.args())
        assert np.sqrt(good) < 0.015           # RMS chamfer distance < 1.5 cm (cells of 2 px ~ 2 cm)
        assert bad > 10 * good


def test_only_what_a_camera_sees_is_compared(walk, rendered):
    """A view whose image ends above the person's knees (the same camera with its image cut
    at that row, the silhouette cut with it): the true body still fits (the legs below the
    image are not scored, and the cut edge gives no outline points), while counting them as
    outside the silhouette would cost more than the body turned front to back."""
    from dataclasses import replace

    rig, frames = rendered
    f = 10
    A, B = np.empty((S.N_CAPSULES, 3)), np.empty((S.N_CAPSULES, 3))
    pts = walk.points[f]
    S.body_capsules(pts, A, B)
    cam = rig.cameras[0]
    knee = cam.project(pts[POINT_NAMES.index("knee_l")][None])[0][0]
    cut = int(knee[1]) - 10                                   # the image's last row, above the knee
    sil = frames[f][cam.name].silhouette
    rows = (cut - sil.y0) // sil.step
    assert 5 < rows < sil.mask.shape[0]
    short = replace(cam, size=(cam.size[0], sil.y0 + rows * sil.step))
    cues = {cam.name: replace(frames[f][cam.name], silhouette=CompactSilhouette(sil.x0, sil.y0, sil.step,
                                                                               sil.mask[:rows]))}
    T = S.SilhouetteTargets.from_cues([short], cues)
    assert T.n_views == 1
    n = T.n_outline[0]
    edge = T.outline[0, :n, 1] >= short.size[1] - sil.step
    assert n > 10 and not edge.any()                         # no outline point along the cut
    good = S.capsules_cost(A, B, S.CAPSULE_RADII_M, *T.args())
    assert np.sqrt(good) < 0.015
    # the old rule: the image as tall as the rig's (what lies below the cut reads as background)
    T_all = S.SilhouetteTargets.from_cues([cam], cues)
    assert S.capsules_cost(A, B, S.CAPSULE_RADII_M, *T_all.args()) > 10 * good


def test_the_outline_term_is_each_points_distance_to_the_nearest_capsule_surface(walk, rendered):
    """The image -> model half of the cost against a brute-force numpy oracle: per outline
    point, the least distance to a projected capsule (segment distance less the radius
    interpolated along it, 0 inside), scaled to metres at that capsule point's depth, squared
    and capped; mean over the points, mean over the views. The half is isolated as the cost
    with the outline points less the cost without them."""
    rig, frames = rendered
    rng = np.random.default_rng(5)
    A, B = np.empty((S.N_CAPSULES, 3)), np.empty((S.N_CAPSULES, 3))
    for f, cues in frames.items():
        T = S.SilhouetteTargets.from_cues(rig.cameras, cues)
        P, fc, grid, dt, dt_off, outline, n_outline = T.args()
        outline = outline + rng.normal(0.0, 6.0, outline.shape)      # points off the surface too
        S.body_capsules(walk.points[f] + rng.normal(0.0, 0.02, walk.points[f].shape), A, B)
        with_pts = S.capsules_cost(A, B, S.CAPSULE_RADII_M, P, fc, grid, dt, dt_off, outline, n_outline)
        without = S.capsules_cost(A, B, S.CAPSULE_RADII_M, P, fc, grid, dt, dt_off, outline, 0 * n_outline)
        views = []
        for c in range(len(P)):
            def project(X):
                h = np.c_[X, np.ones(len(X))] @ P[c].T
                return h[:, :2] / h[:, 2:], h[:, 2]
            (ua, za), (ub, zb) = project(A), project(B)
            ra, rb = fc[c] * S.CAPSULE_RADII_M / za, fc[c] * S.CAPSULE_RADII_M / zb
            q = outline[c, :n_outline[c]]
            d_ab = ub - ua
            t = np.clip(np.einsum("qkx,kx->qk", q[:, None] - ua[None], d_ab) / (d_ab ** 2).sum(1), 0.0, 1.0)
            near = ua[None] + t[..., None] * d_ab[None]
            d = np.linalg.norm(q[:, None] - near, axis=2) - (ra + t * (rb - ra))
            k = d.argmin(axis=1)
            i = np.arange(len(q))
            dm = np.maximum(d[i, k], 0.0) * (za[k] + t[i, k] * (zb - za)[k]) / fc[c]
            views.append(np.minimum(dm ** 2, S.CAP_M ** 2).mean())
        assert n_outline.min() > 10
        np.testing.assert_allclose(with_pts - without, np.mean(views), rtol=1e-9)


def test_fit_brings_a_wrong_heading_back(walk, rendered):
    """Start 40 deg off the true heading: the silhouettes bring the pan back within 15 deg
    (the truth's heading averages hips and shoulders, which counter-rotate in a walk; the
    model's trunk is rigid)."""
    rig, frames = rendered
    lengths = bone_lengths_from_joints(walk.joints)
    fitter = BodyFitter(body_model(lengths, "paper"))
    for f, cues in frames.items():
        T = S.SilhouetteTargets.from_cues(rig.cameras, cues)
        X = walk.joints[f][list(CUE_JOINT_INDEX)]
        jt = walk.joints[f]
        right = jt[J["hip_r"]] - jt[J["hip_l"]] + jt[J["shoulder_r"]] - jt[J["shoulder_l"]]
        true_pan = np.arctan2(right[1], right[0])
        axes = body_axes(X)
        up = axes[:, 2]
        a = true_pan + np.radians(40.0)
        r = np.array([np.cos(a), np.sin(a), 0.0])
        r -= up * (r @ up)
        r /= np.linalg.norm(r)
        start = np.column_stack([r, np.cross(up, r), up])
        res = fitter.fit(X, start, None, T, pan_search_deg=60.0)
        got = np.arctan2(res.axes[1, 0], res.axes[0, 0])
        err = np.degrees(abs((got - true_pan + np.pi) % (2 * np.pi) - np.pi))
        assert err < 15.0, f"frame {f}: pan error {err:.1f} deg"
        assert res.silhouette_cm2 < 5.0


def test_a_search_all_round_scores_the_half_turn_once():
    """A search of 180 deg goes all round once: -180 is +180, which is scored; smaller ones
    are symmetric; a step of 0 searches nothing but the start."""
    assert np.allclose(np.degrees(Fm._search_offsets(30.0, 15.0)), [-30, -15, 0, 15, 30])
    full = np.degrees(Fm._search_offsets(180.0, 30.0))
    assert np.allclose(full, np.arange(-150, 181, 30))
    assert len(np.unique(np.round(full % 360, 6))) == len(full) == 12
    assert np.allclose(Fm._search_offsets(180.0, 0.0), [0.0])


def test_the_cost_summed_in_parts_is_the_whole(walk, rendered):
    """``add_capsules`` over any split of the capsules, then ``partial_cost``, is ``capsules_cost``
    (what the swivel search sums once per limb and adds each candidate's limb to)."""
    rig, frames = rendered
    rng = np.random.default_rng(11)
    A, B = np.empty((S.N_CAPSULES, 3)), np.empty((S.N_CAPSULES, 3))
    for f, cues in frames.items():
        T = S.SilhouetteTargets.from_cues(rig.cameras, cues)
        args = T.args()
        S.body_capsules(walk.points[f] + rng.normal(0.0, 0.03, walk.points[f].shape), A, B)
        whole = S.capsules_cost(A, B, S.CAPSULE_RADII_M, *args)
        for _ in range(5):
            first = rng.random(S.N_CAPSULES) < 0.5
            part = S.new_partial(len(args[0]), args[5].shape[1])
            for caps in (np.flatnonzero(first), np.flatnonzero(~first)):
                S.add_capsules(A, B, S.CAPSULE_RADII_M, caps, *args, part)
            assert S.partial_cost(args[1], args[2], args[6], part) == pytest.approx(whole, rel=1e-12)
            S.reset_partial(part)
            assert S.partial_cost(args[1], args[2], args[6], part) == 0.0


def test_a_swivel_moves_only_its_limb(walk, rendered):
    """The swivel search poses only the moved limb anew (its frames, angles, limit violations and
    joints) and scores only its capsules on top of the others' (``fit._evaluate`` with a limb): for
    every limb and swivel, the same violation and silhouette terms as posing and scoring the whole
    body."""
    rig, frames = rendered
    lengths = bone_lengths_from_joints(walk.joints)
    fitter = BodyFitter(body_model(lengths, "paper"))
    for f, cues in frames.items():
        T = S.SilhouetteTargets.from_cues(rig.cameras, cues)
        X = np.ascontiguousarray(walk.joints[f][list(CUE_JOINT_INDEX)])
        axes = body_axes(X)
        args, sil = fitter._model_args, T.args()
        scratch = Fm._scratch(len(JOINT_NAMES))
        base = np.radians([10.0, -20.0, 5.0, 15.0])
        for limb in range(4):
            Fm._pose(X, axes, base, *args[:-1], sil[:5], 1e4, True, *scratch)      # R, A, B of the base pose
            part = S.new_partial(len(sil[0]), sil[5].shape[1])
            A, B = scratch[5], scratch[6]
            S.add_capsules(A, B, S.CAPSULE_RADII_M, S.SWIVEL_OTHER_CAPSULES[limb], *sil, part)
            for turn in (-45.0, 30.0, 90.0):
                sw = base.copy()
                sw[limb] += np.radians(turn)
                one = Fm._evaluate(X, axes, sw, *args, *sil, Fm._NO_FEET, 1.0, 0.0, *scratch, limb, part,
                                   np.empty_like(part))
                whole = Fm._evaluate(X, axes, sw, *args, *sil, Fm._NO_FEET, 1.0, 0.0, *Fm._scratch(len(JOINT_NAMES)))
                np.testing.assert_allclose(one, whole, rtol=1e-10, atol=1e-12)
                assert whole[1] > 0.0


def test_a_search_of_chosen_limbs_is_the_exhaustive_best_and_keeps_the_others(walk, rendered):
    """``fit`` with ``swivel_limbs`` and a search all round (what the published elbows' search
    asks, ``fusion.solver``): the searched limbs, one after the other, end at the candidate whose
    whole pose scores least (the start included), each judged with the earlier limbs at their
    best; the limbs not searched keep their swivels exactly."""
    rig, frames = rendered
    lengths = bone_lengths_from_joints(walk.joints)
    fitter = BodyFitter(body_model(lengths, "paper"), config=FitConfig(swivel_prior_cost=0.0, swivel_change_cost=0.0))
    offsets = 30.0 * np.arange(-5, 7)
    offsets = offsets[offsets != 0]                     # all round: -180 is 180
    moved = []
    for f, cues in frames.items():
        T = S.SilhouetteTargets.from_cues(rig.cameras, cues)
        X = np.ascontiguousarray(walk.joints[f][list(CUE_JOINT_INDEX)])
        axes = body_axes(X)
        start = np.radians([160.0, -170.0, 5.0, 15.0])        # the arms turned half round
        res = fitter.fit(X, axes, start, T, pan_search_deg=0.0, pan_refine=0,
                         swivel_search_deg=180.0, swivel_step_deg=30.0, swivel_limbs=(True, True, False, False))
        np.testing.assert_array_equal(res.swivel[2:], start[2:])
        expect = start.copy()
        for limb in (0, 1):
            costs = []
            for off in np.concatenate([[0.0], offsets]):
                sw = expect.copy()
                sw[limb] = start[limb] + np.radians(off)
                viol, sil, _ = Fm._evaluate(X, axes, sw, *fitter._model_args, *T.args(), Fm._NO_FEET, 1.0, 0.0,
                                            *Fm._scratch(len(JOINT_NAMES)))
                costs.append(viol + sil)
            expect[limb] = start[limb] + np.radians(np.concatenate([[0.0], offsets])[int(np.argmin(costs))])
        np.testing.assert_allclose(res.swivel, expect, atol=1e-12)
        moved.append(not np.allclose(res.swivel[:2], start[:2]))
    assert any(moved)           # somewhere an arm's turn half round is undone
