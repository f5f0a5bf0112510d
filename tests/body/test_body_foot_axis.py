"""The shoe blob's axis as a foot-direction cue (body.foot_axis), against the studio's rendering."""

import numpy as np
import pytest

from mocap_rt.body import foot_axis as FA
from mocap_rt.body.silhouette import _AUX, rig_projection
from mocap_rt.cues import CameraCues
from mocap_rt.geometry.camera import Camera
from mocap_rt.geometry.rig import ring_rig
from mocap_rt.names import C_FOOT_L, C_FOOT_R, C_HEAD, C_TORSO
from mocap_rt.studio.body_map import POINT_NAMES
from mocap_rt.studio.body_shape import SHOE_RADIUS_M
from mocap_rt.studio.render import RenderConfig, StudioRenderer
from studio_shoes import shoe_covariance

HALF = 0.11   # the studio shoe's half-length (heel -> toe 0.22 m), silhouette.SHOE_HALF_LENGTH_M


def _angle_mod180(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (deg) between two 2D axes, modulo 180."""
    c = abs(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(min(1.0, c))))


@pytest.fixture(scope="module")
def studio():
    rig = ring_rig(6, size=(320, 240))
    return rig, StudioRenderer(rig, config=RenderConfig(noise_sigma_levels=0.0))


def test_rendered_shoe_blob_axis_is_the_projected_heel_toe_axis(studio):
    """Every ring camera, shoes on the floor turned to 8 headings: where the blob is elongated its
    major axis is the projection of heel -> toe (OpenCV projection of the two 3D points), and the
    elongation is largest seen from the side, smaller seen end-on (the ring looks down 28 deg, so an
    end-on shoe still projects longer than wide, along its own projected axis)."""
    rig, ren = studio
    centre = np.array([0.2, -0.3, SHOE_RADIUS_M])
    errs, elong_side, elong_end = [], [], []
    for heading in np.radians(np.arange(0, 180, 22.5)):
        d = np.array([np.cos(heading), np.sin(heading), 0.0])
        heel, toe = centre - HALF * d, centre + HALF * d
        for c, cam in enumerate(rig.cameras):
            cov, xy, area = shoe_covariance(ren, c, heel, toe)
            m = FA.foot_axes({"c": _cues({C_FOOT_L: xy}, {C_FOOT_L: cov}, {C_FOOT_L: area}, {C_FOOT_L: 1.0})}, ["c"])
            a, elong = m[C_FOOT_L, 0, :2], m[C_FOOT_L, 0, 2]
            assert np.isclose(np.linalg.norm(a), 1.0) and a[0] >= 0 and 0.0 <= elong <= 1.0
            lo, hi = np.linalg.eigvalsh(cov)
            assert np.isclose(elong, 1 - lo / hi)
            uv = cam.project(np.array([heel, toe]))[0]
            if elong > 0.5:
                errs.append(_angle_mod180(a, uv[1] - uv[0]))
            view = centre - cam.center
            side = abs(view[0] * d[1] - view[1] * d[0]) / np.linalg.norm(view[:2])   # sin(foot vs line of sight)
            (elong_side if side > 0.95 else elong_end if side < 0.2 else []).append(elong)
    assert len(errs) > 24 and np.max(errs) < 4.0 and np.median(errs) < 1.5
    assert len(elong_side) >= 6 and len(elong_end) >= 6
    assert min(elong_side) > 0.85 and max(elong_end) < min(elong_side) - 0.05


def _fronto_camera(f_px: float = 500.0, dist_m: float = 3.0) -> Camera:
    """A pinhole at (0, -dist, 0.5) looking along +Y (image u = world +X, v = world -Z)."""
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    K = np.array([[f_px, 0, 320], [0, f_px, 240], [0, 0, 1]])
    return Camera("front", (640, 480), K, np.zeros(0), R, -R @ np.array([0.0, -dist_m, 0.5]))


def _points(heel_toe: dict) -> np.ndarray:
    """Body points (len(POINT_NAMES), 3) with only the given feet's heel and toe set."""
    pts = np.zeros((len(POINT_NAMES), 3))
    for side, (heel, toe) in heel_toe.items():
        pts[_AUX[side, 1]], pts[_AUX[side, 0]] = heel, toe
    return pts


def test_cost_is_zero_for_the_truth_and_the_hand_computed_sin2_law():
    """A shoe in a plane facing the camera, turned by phi in that plane from the measured axis:
    its axis leaves the measured line by t * 0.11 sin(phi) m, so the cost is
    1e4 * (0.11 sin phi)^2 / 3 cm^2 per foot, times the weight."""
    cam = _fronto_camera()
    P, f = rig_projection([cam])
    c0 = np.array([0.1, 0.0, 0.3])
    feet = np.zeros((2, 1, FA.N_FOOT_COLS))
    feet[:, 0, :3] = (1.0, 0.0, 1.0)                   # both shoes measured horizontal, fully elongated
    for phi_deg in (0.0, 10.0, 30.0, 60.0, 90.0, 150.0):
        phi = np.radians(phi_deg)
        d = np.array([np.cos(phi), 0.0, np.sin(phi)])
        c1 = c0 + [0.3, 0.0, 0.0]
        pts = _points({0: (c0 - HALF * d, c0 + HALF * d), 1: (c1 + HALF * d, c1 - HALF * d)})   # either way round
        expected = 2 * 1e4 * (HALF * np.sin(phi)) ** 2 / 3.0
        assert FA.foot_axis_cost(pts, P, f, feet) == pytest.approx(expected, abs=1e-9)
        half = feet.copy()
        half[1, 0, 2] = 0.5
        assert FA.foot_axis_cost(pts, P, f, half) == pytest.approx(0.75 * expected, abs=1e-9)
        assert FA.foot_axis_cost(pts, P, f, np.zeros_like(feet)) == 0.0      # nothing measured


def test_cost_grows_with_the_angle_in_every_ring_view():
    """The 6-camera ring, a shoe on the floor measured exactly (its own projection): 0 at the truth,
    then strictly growing as the shoe turns on the floor up to 90 deg, and back down at 180 (mod 180)."""
    rig = ring_rig(6, size=(640, 480))
    P, f = rig_projection(rig.cameras)
    centre, h0 = np.array([0.0, 0.2, 0.05]), 0.4

    def shoe(h):
        d = np.array([np.cos(h), np.sin(h), 0.0])
        return centre - HALF * d, centre + HALF * d

    feet = np.zeros((2, 6, FA.N_FOOT_COLS))
    for c, cam in enumerate(rig.cameras):
        uv = cam.project(np.array(shoe(h0)))[0]
        a = (uv[1] - uv[0]) / np.linalg.norm(uv[1] - uv[0])
        feet[0, c, :3] = a[0], a[1], 1.0
    costs = [FA.foot_axis_cost(_points({0: shoe(h0 + np.radians(e))}), P, f, feet) for e in range(0, 181, 15)]
    assert costs[0] < 1e-12 and costs[-1] < 1e-9
    assert np.all(np.diff(costs[:7]) > 0) and np.all(np.diff(costs[6:]) < 0)
    assert 10.0 < costs[6] < 1e4 * HALF ** 2 / 3.0    # 90 deg off: below the side-view bound in every view


def _cues(xy: dict, cov: dict, area: dict, conf: dict, leg_xy: np.ndarray | None = None) -> CameraCues:
    X, S, A, W = np.full((6, 2), np.nan), np.full((6, 2, 2), np.nan), np.zeros(6), np.zeros(6)
    for k in xy:
        X[k], S[k], A[k], W[k] = xy[k], cov[k], area[k], conf[k]
    return CameraCues("c", 0, X, S, A, W, leg_xy=leg_xy)


def test_measured_axes_and_their_weights():
    """Weight = elongation * confidence on elongated, separate shoe blobs; 0 for a round, small,
    missing or merged blob and for every cue but the feet."""
    th = np.radians(30.0)
    Rm = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    long = Rm @ np.diag([100.0, 9.0]) @ Rm.T
    cov = {C_FOOT_L: long, C_FOOT_R: np.diag([25.0, 25.0]), C_HEAD: long, C_TORSO: long}
    xy = {C_FOOT_L: (100.0, 200.0), C_FOOT_R: (160.0, 200.0), C_HEAD: (130.0, 50.0), C_TORSO: (130, 120)}
    conf = {k: 0.8 for k in xy}
    out = FA.foot_axes({"c": _cues(xy, cov, {k: 300.0 for k in xy}, conf)}, ["c", "absent"])
    assert out.shape == (6, 2, FA.N_FOOT_COLS)
    assert np.all(out[..., 4] == 0)                                      # no legs sent: none measured
    np.testing.assert_allclose(out[C_FOOT_L, 0, :2], [np.cos(th), np.sin(th)], atol=1e-12)
    assert out[C_FOOT_L, 0, 2] == pytest.approx(0.8 * (1 - 9.0 / 100.0))
    assert out[C_FOOT_R, 0, 2] == 0.0                                    # round
    assert np.all(out[[C_HEAD, C_TORSO], :, 2] == 0) and np.all(out[:, 1, 2] == 0)   # not feet / no camera
    small = FA.foot_axes({"c": _cues(xy, cov, {k: FA.MIN_AXIS_AREA_PX - 1 for k in xy}, conf)}, ["c"])
    assert small[C_FOOT_L, 0, 2] == 0.0
    w = np.ones((1, 6))
    w[0, C_FOOT_L] = 0.0                                                 # dropped by fusion's gather
    assert FA.foot_axes({"c": _cues(xy, cov, {k: 300.0 for k in xy}, conf)}, ["c"], w)[C_FOOT_L, 0, 2] == 0.0
    # the two shoes within one major standard deviation each: one merged blob, no axis for either
    cov2 = {**cov, C_FOOT_R: long}
    xy2 = {**xy, C_FOOT_R: (110.0, 205.0)}
    merged = FA.foot_axes({"c": _cues(xy2, cov2, {k: 300.0 for k in xy}, conf, np.full((2, 2), 50.0))}, ["c"])
    assert np.all(merged[[C_FOOT_L, C_FOOT_R], 0, 2] == 0.0) and np.all(merged[[C_FOOT_L, C_FOOT_R], 0, 4] == 0.0)


def test_measured_leg_attachments_along_the_axes():
    """The attachment's offset along the measured axis (px, the axis' sign as in column 0-1) and
    its weight, the cue's: a round blob still measures one; a missing attachment does not."""
    th = np.radians(30.0)
    a = np.array([np.cos(th), np.sin(th)])
    Rm = np.array([[a[0], -a[1]], [a[1], a[0]]])
    cov = {C_FOOT_L: Rm @ np.diag([100.0, 9.0]) @ Rm.T, C_FOOT_R: np.diag([25.0, 25.0])}
    xy = {C_FOOT_L: (100.0, 200.0), C_FOOT_R: (160.0, 200.0)}
    leg = np.array([np.array(xy[C_FOOT_L]) - 7.0 * a, [np.nan, np.nan]])
    out = FA.foot_axes({"c": _cues(xy, cov, {k: 300.0 for k in xy}, {k: 0.8 for k in xy}, leg)}, ["c"])
    assert out[C_FOOT_L, 0, 3] == pytest.approx(-7.0) and out[C_FOOT_L, 0, 4] == 0.8
    assert out[C_FOOT_R, 0, 4] == 0.0
    leg[1] = (160.0, 190.0)                                                # above a round blob
    out = FA.foot_axes({"c": _cues(xy, cov, {k: 300.0 for k in xy}, {k: 0.8 for k in xy}, leg)}, ["c"])
    axis = out[C_FOOT_R, 0, :2]
    assert out[C_FOOT_R, 0, 4] == 0.8 and out[C_FOOT_R, 0, 3] == pytest.approx(axis @ [0.0, -10.0])


def test_leg_cost_is_zero_at_the_ankle_and_the_capped_square_at_the_turned_ankle():
    """A shoe facing +X in the fronto-parallel plane, its ankle 0.06 m behind and 0.08 m above
    its centre; a camera looking along +Y sees the ankle 0.06 m to the heel side and the foot turned
    round would put it 0.06 m to the toe side. The attachment measured at the ankle costs 0, at the
    turned ankle's place min(0.12, cap)^2 (cm^2, the views' mean per foot), linearly in between;
    the axis term's weight 0 leaves the legs' term alone."""
    from mocap_rt.body.silhouette import _ANKLES, _P

    cam = _fronto_camera()
    P, f = rig_projection([cam])
    c0 = np.array([0.1, 0.0, 0.3])
    pts = _points({0: (c0 - [HALF, 0, 0], c0 + [HALF, 0, 0])})
    pts[_ANKLES[0]] = c0 + [-0.06, 0.0, 0.08]
    pts[_P["pelvis"]], pts[_P["neck"]] = c0 + [0.0, 0.0, 0.6], c0 + [0.0, 0.0, 1.1]   # the body's up: +Z
    z = 3.0                                                            # the shoe's depth
    feet = np.zeros((2, 1, FA.N_FOOT_COLS))
    feet[0, 0] = (1.0, 0.0, 0.0, 0.0, 1.0)                             # axis +u, attachment t px
    d_m = 0.12
    full = 1e4 * min(d_m, FA.LEG_CAP_M) ** 2
    for t_m, expected in ((-0.06, 0.0), (-0.1, 0.0), (0.0, 0.5 * full), (0.06, full), (0.09, full)):
        feet[0, 0, 3] = t_m * 500.0 / z
        assert FA.foot_axis_cost(pts, P, f, feet) == pytest.approx(expected, rel=1e-6, abs=1e-9)
    feet[0, 0, 4] = 0.5
    assert FA.foot_axis_cost(pts, P, f, feet) == pytest.approx(0.5 * full, rel=1e-6)


def test_axes_follow_a_views_relabelled_feet():
    """A view whose left/right foot pixels were exchanged (labels.fix_left_right) exchanges its
    two feet's axes; the other views keep theirs."""
    rng = np.random.default_rng(1)
    axes = rng.normal(size=(6, 3, 3))
    uv = rng.normal(size=(3, 6, 2))
    uv[2, C_FOOT_R] = np.nan
    after = uv.copy()
    after[1, [C_FOOT_L, C_FOOT_R]] = uv[1, [C_FOOT_R, C_FOOT_L]]
    after[2, [C_FOOT_L, C_FOOT_R]] = uv[2, [C_FOOT_R, C_FOOT_L]]   # one foot seen: label moved to the other
    out = FA.follow_relabelling(axes, uv, after)
    np.testing.assert_array_equal(out[:, 0], axes[:, 0])
    for c in (1, 2):
        np.testing.assert_array_equal(out[C_FOOT_L, c], axes[C_FOOT_R, c])
        np.testing.assert_array_equal(out[C_FOOT_R, c], axes[C_FOOT_L, c])
        np.testing.assert_array_equal(out[C_HEAD, c], axes[C_HEAD, c])


def test_shoe_axes_bring_the_fitted_knees_to_the_truth(data_dir, studio):
    """A studio kick (Bandai, the truth's body points): the studio renders the person (silhouettes)
    and each shoe alone (its blob moments), and the body is fitted from the truth's cues with the
    heading started 30 deg off, swivels carried over frames, with and without the shoe axes. The
    feet's directions pull the legs' swivels towards the truth: the knees land nearer (measured
    77 -> 58 mm over these 16 frames) and the legs' and trunk's joints on average no further
    (25 -> 22 mm). The arms are left out: their elbows, measured on the silhouettes, move with
    the pan the shoes turn by a few degrees (the left elbow 122 -> 157 mm, MPJPE 34 -> 35 mm)."""
    from mocap_rt.body.analytic import AnalyticConfig, analytic_pose
    from mocap_rt.body.estimate import bone_lengths_from_joints
    from mocap_rt.body.fit import BodyFitter
    from mocap_rt.body.kinematics import forward_kinematics
    from mocap_rt.body.silhouette import SilhouetteTargets
    from mocap_rt.body.skeleton import J, body_model
    from mocap_rt.fusion.evaluate import truth_silhouette, trunk_axes
    from mocap_rt.io.bvh import read_bvh
    from mocap_rt.names import CUE_JOINT_INDEX, JOINT_NAMES
    from mocap_rt.studio.body_map import body_motion
    from mocap_rt.studio.body_shape import body_primitives

    rig, ren = studio
    clip = read_bvh(data_dir / "bvh" / "bandai_namco" / "dataset-1_kick_normal_001.bvh")
    motion = body_motion(clip, fps=30, n_frames=48, start_s=1.0, placement="centre")
    joints = motion.points[:, :len(JOINT_NAMES)]
    model = body_model(bone_lengths_from_joints(joints), "paper")
    fitter = BodyFitter(model)
    fwd, left, up = trunk_axes(joints)
    knees = [J["knee_l"], J["knee_r"]]
    legs_trunk = [J[n] for n in JOINT_NAMES if not n.startswith(("shoulder", "elbow", "wrist", "hand"))]
    swivel = {False: np.zeros(4), True: np.zeros(4)}
    knee_err, mpjpe = {False: [], True: []}, {False: [], True: []}
    for fr in range(0, 48, 3):
        pts = motion.points[fr]
        prims = body_primitives(pts)
        cues = {}
        for c, cam in enumerate(rig.cameras):
            m = ren.render(c, prims, fr).mask
            sil = truth_silhouette(np.packbits(m, axis=1), m.shape[1])
            xy, cov, area = np.full((6, 2), np.nan), np.full((6, 2, 2), np.nan), np.zeros(6)
            for k, s in ((C_FOOT_L, "l"), (C_FOOT_R, "r")):
                shoe = shoe_covariance(ren, c, pts[POINT_NAMES.index(f"heel_{s}")], pts[POINT_NAMES.index(f"toe_{s}")])
                if shoe is not None:
                    cov[k], xy[k], area[k] = shoe
            cues[cam.name] = CameraCues(cam.name, fr, xy, cov, area, (area > 0).astype(float), silhouette=sil)
        targets = SilhouetteTargets.from_cues(rig.cameras, cues)
        feet = FA.foot_axes(cues, rig.names)
        X = pts[list(CUE_JOINT_INDEX)]
        turn = np.radians(30.0)
        axes = np.column_stack([-np.cos(turn) * left[fr] + np.sin(turn) * fwd[fr],
                                np.sin(turn) * left[fr] + np.cos(turn) * fwd[fr], up[fr]])
        for use in (False, True):
            res = fitter.fit(X, axes, swivel[use], targets, feet=feet if use else None)
            swivel[use] = res.swivel
            assert (res.foot_axis_cm2 > 0) == use
            # the pose as the tracker solves it: its elbows on the silhouettes, as the fit scored them
            got = forward_kinematics(model, *analytic_pose(model, X, res.axes, AnalyticConfig(), res.swivel,
                                                           targets.args()[:5], 1e4))[0]
            knee_err[use].append(np.linalg.norm(got[knees] - joints[fr][knees], axis=1).mean())
            mpjpe[use].append(np.linalg.norm(got[legs_trunk] - joints[fr][legs_trunk], axis=1).mean())
    assert np.mean(knee_err[True]) < np.mean(knee_err[False]) - 0.010
    assert np.mean(mpjpe[True]) <= np.mean(mpjpe[False])


def test_fit_refuses_axes_of_another_rig():
    """Shoe axes for a different number of cameras than the targets' would be read out of bounds
    by the kernel: a ValueError naming the shapes instead."""
    from mocap_rt.body.fit import BodyFitter
    from mocap_rt.body.silhouette import SilhouetteTargets
    from mocap_rt.body.skeleton import BoneLengths, body_model
    from mocap_rt.names import CUE_JOINT_INDEX

    model = body_model(BoneLengths(), "paper")
    rig = ring_rig(6, size=(320, 240))
    X = model.rest_positions()[list(CUE_JOINT_INDEX)]
    with pytest.raises(ValueError, match=r"feet must be .*\(6, 6, 5\).*\(6, 4, 5\)"):
        BodyFitter(model).fit(X, np.eye(3), None, SilhouetteTargets(rig.cameras), feet=np.zeros((6, 4, 5)))
