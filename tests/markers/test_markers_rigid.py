"""Rigid preprocessing: absolute orientation against scipy oracles, GPA, marker choice."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import orthogonal_procrustes
from scipy.spatial.transform import Rotation

from mocap_rt.markers.rigid import absolute_orientation, apply_pose, fit_rigid_segment, select_markers


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), k=st.integers(3, 8))
def test_rigid_rotation_matches_align_vectors_and_orthogonal_procrustes(seed, k):
    rng = np.random.default_rng(seed)
    src = rng.normal(size=(k, 3))
    tgt = Rotation.random(random_state=seed).apply(src) + rng.normal(size=3) + 0.05 * rng.normal(size=(k, 3))
    c, r, t = absolute_orientation(tgt, src)
    assert c[0] == 1.0
    # oracle 1: Rotation.align_vectors on centred points (Kabsch)
    ref, _ = Rotation.align_vectors(tgt - tgt.mean(0), src - src.mean(0))
    np.testing.assert_allclose(r[0], ref.as_matrix(), atol=1e-9)
    # oracle 2: orthogonal_procrustes finds Q minimising ||A Q - B||: A = src, B = tgt (row vectors)
    q, _ = orthogonal_procrustes(src - src.mean(0), tgt - tgt.mean(0))
    if np.linalg.det(q) > 0:  # scipy has no reflection fix; compare when it found a rotation
        np.testing.assert_allclose(r[0], q.T, atol=1e-9)
    np.testing.assert_allclose(t[0], tgt.mean(0) - r[0] @ src.mean(0), atol=1e-12)


def test_reflection_fix_returns_a_proper_rotation():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(6, 3))
    tgt = src * np.array([1.0, 1.0, -1.0])  # mirror image: best orthogonal map is a reflection
    q, _ = orthogonal_procrustes(src, tgt)
    assert np.linalg.det(q) < 0
    _, r, _ = absolute_orientation(tgt, src)
    assert np.linalg.det(r[0]) == pytest.approx(1.0)


def test_similarity_recovers_scale_and_per_frame_poses_with_weights_and_gaps():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(5, 3))
    rots = Rotation.random(20, random_state=2)
    scale = rng.uniform(0.5, 2.0, 20)
    trans = rng.normal(size=(20, 3))
    tgt = scale[:, None, None] * np.einsum("fab,kb->fka", rots.as_matrix(), src) + trans[:, None]
    tgt[3, 1] = np.nan  # a gap: 4 markers remain
    tgt[4, :3] = np.nan  # only 2 markers: no pose
    c, r, t = absolute_orientation(tgt, src, similarity=True)
    good = np.arange(20) != 4
    np.testing.assert_allclose(c[good], scale[good], rtol=1e-10)
    np.testing.assert_allclose(r[good], rots.as_matrix()[good], atol=1e-10)
    np.testing.assert_allclose(t[good], trans[good], atol=1e-10)
    assert np.isnan(c[4]) and np.isnan(r[4]).all() and np.isnan(t[4]).all()


def test_gpa_recovers_the_rigid_template_up_to_a_rigid_motion_despite_gaps():
    rng = np.random.default_rng(4)
    z = rng.normal(scale=0.1, size=(5, 3))
    rots = Rotation.random(60, random_state=5).as_matrix()
    x_full = np.einsum("fab,kb->fka", rots, z) + rng.normal(size=(60, 1, 3))
    x = x_full.copy()
    x[rng.random((60, 5)) < 0.15] = np.nan
    fit = fit_rigid_segment(x)
    # template is z up to a rigid motion: pairwise distances agree
    d_true = np.linalg.norm(z[:, None] - z[None], axis=2)
    d_fit = np.linalg.norm(fit.template[:, None] - fit.template[None], axis=2)
    np.testing.assert_allclose(d_fit, d_true, atol=1e-10)
    seen = np.isfinite(x).all(axis=2)
    np.testing.assert_allclose(fit.corrected[seen], x[seen], atol=1e-10)
    assert fit.rms_m < 1e-10
    # gaps in frames that keep a pose (>= 3 markers seen) are filled with the true position
    gap = ~seen & fit.has_pose[:, None]
    assert gap.sum() > 10
    np.testing.assert_allclose(fit.corrected[gap], x_full[gap], atol=1e-10)
    assert np.isnan(fit.corrected[~fit.has_pose]).all()


def test_gpa_reduces_noise_and_ranks_the_sliding_marker_last():
    rng = np.random.default_rng(6)
    z = np.array([[0.0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1], [0.05, 0.05, 0.0]])
    rots = Rotation.random(200, random_state=7).as_matrix()
    clean = np.einsum("fab,kb->fka", rots, z) + rng.normal(size=(200, 1, 3))
    noise = rng.normal(scale=0.001, size=clean.shape)
    noise[:, 3] *= 8.0  # marker 3 slides a lot
    fit = fit_rigid_segment(clean + noise)
    err_raw = np.linalg.norm(clean + noise - clean, axis=2).mean()
    err_fit = np.linalg.norm(fit.corrected - clean, axis=2).mean()
    assert err_fit < err_raw
    order = select_markers(fit.template, fit.marker_error)
    assert order[-1] == 3
    assert sorted(order) == [0, 1, 2, 3, 4]


def test_select_markers_skips_a_collinear_third_marker():
    template = np.array([[0.0, 0, 0], [0.1, 0, 0], [0.05, 0.0, 0.0], [0.0, 0.08, 0.0]])
    order = select_markers(template, np.array([1.0, 2.0, 3.0, 4.0]))
    assert list(order[:3]) == [0, 1, 3]


def test_apply_pose_inverts_absolute_orientation():
    rng = np.random.default_rng(8)
    src = rng.normal(size=(4, 3))
    tgt = rng.normal(size=(3, 4, 3))
    c, r, t = absolute_orientation(tgt, src, similarity=True)
    fitted = apply_pose(c, r, t, src)
    # residual is orthogonal to any further similarity change: refitting gives the same transform
    c2, r2, t2 = absolute_orientation(fitted, src, similarity=True)
    np.testing.assert_allclose(c2, c)
    np.testing.assert_allclose(r2, r, atol=1e-12)


def test_similarity_gpa_absorbs_per_frame_scale_that_rigid_gpa_cannot():
    rng = np.random.default_rng(9)
    z = rng.normal(scale=0.1, size=(4, 3))
    rots = Rotation.random(50, random_state=10).as_matrix()
    scale = rng.uniform(0.9, 1.1, 50)
    x = scale[:, None, None] * np.einsum("fab,kb->fka", rots, z) + rng.normal(size=(50, 1, 3))
    sim = fit_rigid_segment(x, similarity=True)
    rig = fit_rigid_segment(x, similarity=False)
    assert sim.rms_m < 1e-10
    assert rig.rms_m > 1e-3
    np.testing.assert_allclose(np.mean(sim.scale), 1.0, atol=1e-9)
    np.testing.assert_allclose(sim.scale / sim.scale[0], scale / scale[0], rtol=1e-9)
