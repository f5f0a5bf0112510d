"""Left/right identity and heading as competing hypotheses (fusion.identity, BodyTracker)."""

import numpy as np
import pytest

from mocap_rt.fusion.config import FusionConfig
from mocap_rt.fusion.evaluate import heading_deg, mirrored_frames, truth_camera_cues, wrap_deg
from mocap_rt.fusion.filter import CueFilter
from mocap_rt.fusion.identity import (ALTERNATIVE_PAIRS, ALTERNATIVES, IdentityConfig, IdentityState,
                                      crossed_legs_cm2, decide, feet_together, feet_told_apart, segment_distance,
                                      swap_pairs, swap_swivel)
from mocap_rt.fusion.tracker import BodyTracker
from mocap_rt.io.recording import Recording
from mocap_rt.names import CUE_NAMES, J

FL, FR = CUE_NAMES.index("foot_l"), CUE_NAMES.index("foot_r")
HL, HR = CUE_NAMES.index("hand_l"), CUE_NAMES.index("hand_r")
# frames a cold start may take to acquire the identity (1/3 s)
ACQUIRE_FRAMES = 10


def test_filter_swap_exchanges_the_whole_track_state():
    f = CueFilter(3)
    f.update(0.0, np.array([[0.0, 0, 0], [1, 1, 1], [np.nan] * 3]))
    f.update(0.1, np.array([[0.1, 0, 0], [1, 1, 1.2], [np.nan] * 3]))
    before = [a.copy() for a in (f.pos, f.vel, f.cov, f.alive, f.last_update_s, f.last_meas)]
    f.swap(0, 1)
    for b, a in zip(before, (f.pos, f.vel, f.cov, f.alive, f.last_update_s, f.last_meas)):
        np.testing.assert_array_equal(a[[1, 0, 2]], b)
    # the swapped tracks predict each other's paths
    np.testing.assert_allclose(f.predict_at(0.2)[1], f.pos[1] + 0.1 * f.vel[1])


def test_swaps_exchange_exactly_their_pairs_and_undo_themselves():
    X = np.arange(18.0).reshape(6, 3)
    for k, pairs in enumerate(ALTERNATIVE_PAIRS):
        Y = swap_pairs(X, k)
        moved = {c for p in pairs for c in p}
        for c in range(6):
            np.testing.assert_array_equal(Y[c], X[c] if c not in moved else X[[b for p in pairs for b in p
                                                                              if c in p and b != c][0]])
        np.testing.assert_array_equal(swap_pairs(Y, k), X)
        np.testing.assert_array_equal(swap_swivel(swap_swivel(np.arange(4.0), k), k), np.arange(4.0))
    assert ALTERNATIVES[2] == "mirror" and len(ALTERNATIVE_PAIRS[2]) == 2


def test_decide_switches_on_consistent_evidence_and_never_on_noise():
    cfg = IdentityConfig()
    feet = ALTERNATIVES.index("feet")
    # the feet alternative 2 units cheaper every frame: a leaky sum g (1 - d^n) / (1 - d) passes the
    # acquisition threshold after n frames (computed here from the config, not assumed)
    state = IdentityState()
    gain = 2.0
    need = cfg.switch_evidence * cfg.acquire_factor
    n_expected = int(np.ceil(np.log(1 - need * (1 - cfg.decay) / gain) / np.log(cfg.decay)))
    switched_at = taken = None
    for n in range(1, 40):
        costs = np.array([10.0, 30.0, 10.0 - gain, 50.0])
        taken = decide(state, costs, cfg)
        if taken >= 0:
            switched_at = n
            break
    assert taken == feet and switched_at in (n_expected, n_expected + 1)   # > vs >= at the boundary
    assert state.switches == 1 and np.all(state.evidence == 0)
    assert state.last_switch == (feet, switched_at)       # cheaper in every frame so far
    # a frame where the alternative is not cheaper restarts the run that a switch carries back
    state = IdentityState()
    for g in (3.0, 3.0, -1.0, 3.0, 3.0):
        decide(state, np.array([10.0, 30.0, 10.0 - g, 50.0]), cfg)
    assert state.won[feet] == 2 and state.won[ALTERNATIVES.index("hands")] == 0
    # alternating evidence (noise) never switches, however long it lasts
    state = IdentityState()
    for n in range(400):
        g = 5.0 if n % 2 else -5.0
        assert decide(state, np.array([10.0, 10.0 + g, 10.0 - g, 10.0 + 2 * g]), cfg) == -1
    # a clearly better alternative whose costs are not finite in some frames is still found
    state = IdentityState()
    hits = [decide(state, np.array([20.0, 5.0 if n % 3 else np.inf, 25.0, 30.0]), cfg) for n in range(30)]
    assert ALTERNATIVES.index("hands") in hits


def test_a_feet_switch_reaches_over_the_whole_track_until_something_decided_the_feet():
    """Past the acquisition a switch reaches back over the frames it won; but feet that no frame
    told apart (standing closer together than the hips) and no switch exchanged still have the
    cold start's labels, so their first switch reaches back over the whole track."""
    cfg = IdentityConfig()
    feet, hands, mirror = (ALTERNATIVES.index(a) for a in ("feet", "hands", "mirror"))

    def run(decided: bool, k: int, quiet: int = 40) -> IdentityState:
        state = IdentityState(feet_decided=decided)
        for _ in range(quiet):                            # past the acquisition, nothing cheaper
            assert decide(state, np.array([10.0, 12.0, 12.0, 14.0]), cfg) == -1
        costs = np.full(4, 14.0)
        costs[0], costs[1 + k] = 10.0, 0.0                # then alternative k 10 units cheaper a frame
        while decide(state, costs, cfg) < 0:
            pass
        assert state.frames > cfg.acquire_frames and state.last_switch[0] == k
        return state

    undecided, decided = run(False, feet), run(True, feet)
    won = int(decided.last_switch[1])
    assert 1 <= won < 10                                   # the frames it won in a row
    assert undecided.last_switch[1] == undecided.frames    # every frame of the track
    assert undecided.feet_decided                          # the switch decided them
    # the hands' switch is not the feet's: it reaches as far as it won and decides nothing of the feet
    hands_only = run(False, hands)
    assert hands_only.last_switch[1] == won and not hands_only.feet_decided
    assert run(False, mirror).feet_decided
    state = IdentityState(feet_decided=True)
    state.reset()                                          # a new track: its feet undecided again
    assert not state.feet_decided


def test_the_mirror_needs_evidence_for_both_pairs():
    """First frames measured in the closed loop (costs: current, hands, feet, mirror). Wholly
    mirrored (backwards walk): the feet swap alone is also cheaper than the current labels, so
    the mirror is taken. Only the hands wrong (feet crossing, reversed kick): the mirror leads
    the hands swap by 0.1-1.3 units but the feet swap alone is dearer: the hands alone switch."""
    cfg = IdentityConfig()
    hands, mirror = ALTERNATIVES.index("hands"), ALTERNATIVES.index("mirror")
    for costs, want in (([64.9, 28.1, 59.0, 26.3], mirror), ([53.7, 11.4, 56.5, 11.3], hands),
                        ([52.6, 29.4, 60.3, 28.1], hands)):
        assert decide(IdentityState(), np.array(costs), cfg) == want
    # a mirror clearly ahead of both single swaps is taken even if one swap alone is dearer
    # (jumping jacks' frame 8: 110.1, 236.8, 119.9, 67.1, after evidence built up)
    state = IdentityState()
    state.evidence[:] = [-700.0, -60.0, -10.0]
    assert decide(state, np.array([110.1, 236.8, 119.9, 67.1]), cfg) == mirror


def _truth_cues(truth, names, widths, f, rng, swaps) -> dict:
    """The truth's 2D cues of frame f (+1 px noise, with silhouettes) per camera, each pair in
    ``swaps`` labelled the wrong way round in every view."""
    cues = truth_camera_cues(truth, names, f, f, 1.0, rng, widths)
    for a, b in swaps:
        for cc in cues.values():
            for arr in (cc.xy, cc.cov, cc.area, cc.confidence):
                arr[[a, b]] = arr[[b, a]]
    return cues


def _truth_setup(rec_dir, noise_seed: int = 0):
    """(recording, truth, camera names, widths, a fresh BodyTracker, rng) for feeding
    ``_truth_cues`` of ``rec_dir``."""
    rec = Recording(rec_dir)
    tracker = BodyTracker(rec.rig, FusionConfig(fps=rec.fps))
    return (rec, rec.truth, list(rec.rig.names), {c.name: int(c.size[0]) for c in rec.rig.cameras}, tracker,
            np.random.default_rng(noise_seed))


def _truth_run(rec_dir, swap_feet: bool, swap_tracks_at: int | None = None, swap_hands: bool = False,
               noise_seed: int = 0, live: bool = False):
    """Truth 2D cues (+1 px noise) and truth silhouettes through BodyTracker, optionally with
    the feet (``swap_hands``: the hands) labelled the wrong way round in every view, or with the
    tracker's own foot tracks exchanged before frame ``swap_tracks_at``. Returns (joints (F, 20,
    3), truth joints, foot cue errors (F, 2) m, identity switches made up to each frame (F,),
    hand cue errors (F, 2) m). The foot errors are those of ``step`` (offline), or with ``live``
    of the pose the service publishes (``fit_frame``, before the frame's identity)."""
    rec, truth, names, widths, tracker, rng = _truth_setup(rec_dir, noise_seed)
    joints, err, switches, hand_err, live_err = [], [], [], [], []
    swaps = [p for p, on in (((FL, FR), swap_feet), ((HL, HR), swap_hands)) if on]
    for f in range(rec.n_frames):
        cues = _truth_cues(truth, names, widths, f, rng, swaps)
        if f == swap_tracks_at:
            tracker.filter.swap(FL, FR)
        published = tracker.fit_frame(f, cues)      # what the service publishes ...
        live_err.append(np.linalg.norm(published.cues_ik[[FL, FR]] - truth["cues"][f][[FL, FR]], axis=1))
        r = tracker.identify_frame(published)       # ... and what step (offline) keeps
        joints.append(r.joints)
        err.append(np.linalg.norm(r.cues_ik[[FL, FR]] - truth["cues"][f][[FL, FR]], axis=1))
        switches.append(tracker.identity.switches)
        hand_err.append(np.linalg.norm(r.cues_ik[[HL, HR]] - truth["cues"][f][[HL, HR]], axis=1))
    rec.close()
    if live:
        err = live_err
    return np.array(joints), np.asarray(truth["joints"]), np.array(err), np.array(switches), np.array(hand_err)


def test_feet_labelled_the_wrong_way_in_every_view_are_put_right(backwards_walk):
    """Every view agrees on the wrong feet (what a cold start's "facing the camera" guess gives
    for a person seen from behind): the crossed legs fit neither the silhouettes nor the joint
    limits, so the feet hypothesis wins and the labels are exchanged for good."""
    _, _, err, _, _ = _truth_run(backwards_walk, swap_feet=True)
    assert np.median(err[:2]) > 0.1                           # mirrored at first ...
    assert np.percentile(err[ACQUIRE_FRAMES:], 95) < 0.03     # ... then on the right feet for good


def test_feet_tracks_exchanged_mid_track_are_put_right_from_the_next_frame(backwards_walk_3s):
    """After the identity was acquired the feet tracks are exchanged (what a crossing that
    perception followed leaves): every view then agrees with the wrong prediction, and only
    the hypotheses can see it. The switch is decided after the frame's pose went out
    (``identify_frame``): the pose the service published of that frame still has the wrong feet,
    the next ones the right; ``step`` gives that frame refitted with the right feet."""
    at = ACQUIRE_FRAMES + 15
    _, _, err, switches, _ = _truth_run(backwards_walk_3s, swap_feet=False, swap_tracks_at=at, live=True)
    assert np.percentile(err[ACQUIRE_FRAMES:at], 95) < 0.03     # right before ...
    assert np.median(err[at:at + 2]) > 0.1                       # ... wrong at once ...
    s = at + int(np.argmax(switches[at:] > switches[at - 1]))    # ... until the frame that switched
    assert switches[s] > switches[at - 1], "never switched back"
    assert err[s].min() > 0.1                                    # its published pose: still wrong
    assert np.percentile(err[s + 1:], 95) < 0.03                 # from the next frame: right for good
    _, _, err_step, switches_step, _ = _truth_run(backwards_walk_3s, swap_feet=False, swap_tracks_at=at)
    assert np.array_equal(switches_step, switches)               # the same run ...
    assert err_step[s].max() < 0.03                              # ... whose switching frame step refits


def test_offline_carries_a_switch_back_over_the_frames_whose_evidence_it_took(backwards_walk):
    """Every view labels the feet the wrong way from the first frame: the poses published live
    have them wrong until the identity, still acquiring, switches (frame 10 here). Before that
    the labels were the cold start's guess, so ``run_tracker`` (``mocap-rt process``) gives the
    track's earlier frames the switch's labels too: offline no frame has the feet exchanged."""
    from mocap_rt.fusion.offline import run_tracker

    rec, truth, names, widths, tracker, rng = _truth_setup(backwards_walk)

    def foot_err(r, f):
        return np.linalg.norm(r.cues_ik[[FL, FR]] - truth["cues"][f][[FL, FR]], axis=1)

    live, fit_frame = [], tracker.fit_frame

    def published(frame, cues):
        r = fit_frame(frame, cues)
        live.append(foot_err(r, frame))
        return r

    tracker.fit_frame = published
    results = run_tracker(tracker, lambda i, _: (i, _truth_cues(truth, names, widths, i, rng, [(FL, FR)])),
                          rec.n_frames, progress=False)
    rec.close()
    k, back = tracker.identity.last_switch
    assert tracker.identity.switches == 1 and ALTERNATIVES[k] == "feet"
    assert back > ACQUIRE_FRAMES // 2 and np.min(live[:back]) > 0.1   # published wrong until the switch ...
    err = np.array([foot_err(r, r.frame) for r in results])
    assert err.max() < 0.03                                      # ... right offline from the first frame
    joints = np.array([r.joints for r in results])
    assert np.nansum(mirrored_frames(joints, np.asarray(truth["joints"])[:len(joints)])) == 0


def test_a_cold_start_is_identified_after_its_pose(kick_reversed):
    """A cold start whose hands every view labels the wrong way round: ``fit_frame`` (the pose the
    service publishes) does not score the identity, even while the track acquires it; the frame's
    ``identify_frame`` switches the hands and returns the frame refitted with them, and the next
    frame's pose has them from the start."""
    rec, truth, names, widths, tracker, rng = _truth_setup(kick_reversed)

    def cues(f):
        return _truth_cues(truth, names, widths, f, rng, [(HL, HR)])

    def hand_err(r, f):
        return np.linalg.norm(r.cues_ik[[HL, HR]] - truth["cues"][f][[HL, HR]], axis=1)

    published = tracker.fit_frame(0, cues(0))
    assert tracker.identity.frames == 0 and tracker.identity.switches == 0
    assert hand_err(published, 0).min() > 0.3                    # published with the views' labels
    kept = tracker.identify_frame(published)
    assert tracker.identity.frames == 1 and tracker.identity.switches == 1
    assert hand_err(kept, 0).max() < 0.05 and hand_err(published, 0).min() > 0.3
    assert hand_err(tracker.fit_frame(1, cues(1)), 1).max() < 0.05
    rec.close()



def test_a_hand_measured_on_the_heads_blob_exchanges_no_hands(kick_reversed):
    """The cold start of the test above, its first frame's hand measured from a view that found it
    on the head's blob (``views.hands_on_head``: such a view cannot tell which arm reached up): the
    frame scores the alternatives that exchange the hands as the current labelling, so it switches
    nothing; the next frame, measured as usual, switches the hands."""
    rec, truth, names, widths, tracker, rng = _truth_setup(kick_reversed)

    def cues(f):
        return _truth_cues(truth, names, widths, f, rng, [(HL, HR)])

    published = tracker.fit_frame(0, cues(0))
    scored, *rest = tracker._pending
    assert scored[-1] is False                                   # nothing on the head in the truth
    tracker._pending = ((*scored[:-1], True), *rest)
    tracker.identify_frame(published)
    assert tracker.identity.switches == 0
    tracker.identify_frame(tracker.fit_frame(1, cues(1)))
    assert tracker.identity.switches == 1
    rec.close()

@pytest.mark.parametrize("noise_seed", range(6))
def test_cold_start_with_the_hands_wrong_keeps_the_right_feet(kick_reversed, noise_seed):
    """A cold start whose hands every view labels the wrong way round, the feet right: the
    mirror (hands and feet exchanged, the heading free) fits 1-2 units better than the hands
    swap alone in most pixel-noise draws, while exchanging the feet alone is 3-5 units worse.
    The mirror must not be taken on that lead: the feet it adds have no evidence of their own,
    and exchanged they stayed so for the whole clip (4 of these 6 draws before the rule). Checked
    over the acquisition (the cold start's decision): later, as the kick begins, the costs can
    favour the wrong feet for a few frames (one draw switches them for frames 10-13), which is
    the scoring's matter, not this rule's."""
    _, tj, err, switches, hand_err = _truth_run(kick_reversed, swap_feet=False, swap_hands=True,
                                                noise_seed=noise_seed)
    apart = np.linalg.norm(tj[:, J["foot_l"]] - tj[:, J["foot_r"]], axis=1)
    assert np.min(apart) > 0.5                                   # exchanged feet would be 0.5 m+ off
    assert switches[-1] >= 1                                     # the wrong hands were seen and switched ...
    assert np.max(hand_err[ACQUIRE_FRAMES:]) < 0.1               # ... and stay right
    wrong = np.flatnonzero(err[:ACQUIRE_FRAMES].max(axis=1) >= 0.1)
    assert wrong.size == 0, f"feet exchanged in frames {wrong}"


def test_walking_backwards_is_neither_mirrored_nor_turned_round(backwards_walk):
    """The walk backwards with right labels: the walking direction must not turn the body
    round (the issue-5 behaviour faced the body where it walked and mirrored it)."""
    joints, tj, _, _, _ = _truth_run(backwards_walk, swap_feet=False)
    mir = mirrored_frames(joints, tj)
    herr = np.abs(wrap_deg(heading_deg(joints) - heading_deg(tj)))
    assert np.nansum(mir[ACQUIRE_FRAMES:]) == 0
    assert np.nanmax(herr[ACQUIRE_FRAMES:]) < 45.0 and np.nanmedian(herr) < 15.0


def test_arms_raised_sideways_overhead_are_neither_mirrored_nor_turned(jumping_jacks):
    """Jumping jacks with the truth's cues: the arms pass the shoulders sideways to overhead,
    where one Euler name reads the shoulder 200-230 deg out of range and the pan fit turned the
    body to lower it (heading p95 41 deg); judged as swing and twist (``limb_geometry``) the
    raised arms cost nothing, the body keeps its heading and is never mirrored."""
    joints, tj, _, switches, _ = _truth_run(jumping_jacks, swap_feet=False)
    mir = mirrored_frames(joints, tj)
    herr = np.abs(wrap_deg(heading_deg(joints) - heading_deg(tj)))
    print(f"mirrored {np.nansum(mir)} of {len(mir)}, heading p95 {np.nanpercentile(herr, 95):.0f} deg, "
          f"switches {switches[-1]}")
    assert np.nansum(mir) == 0
    assert np.nanpercentile(herr, 95) < 20.0


@pytest.mark.slow
def test_closed_loop_backwards_walk_is_not_mirrored(backwards_walk, tmp_path):
    """End to end as ``mocap-rt process`` runs it: rendered images -> perception -> fusion with
    the silhouettes -> body; walking backwards, the body must not be mirrored or turned round."""
    from mocap_rt.fusion.offline import process_recording

    out = process_recording(backwards_walk, tmp_path, progress=False)
    rec = Recording(backwards_walk)
    tj = np.asarray(rec.truth["joints"])[out.frames]
    rec.close()
    joints = np.where(out.joint_valid[..., None], out.joints, np.nan)
    mir = mirrored_frames(joints, tj)
    herr = np.abs(wrap_deg(heading_deg(joints) - heading_deg(tj)))
    assert np.nansum(mir[ACQUIRE_FRAMES:]) == 0, f"mirrored frames: {np.flatnonzero(mir == 1)}"
    assert np.nanmax(herr[ACQUIRE_FRAMES:]) < 60.0
    assert out.accuracy.mpjpe_mm < 100.0


def test_feet_exchanged_side_by_side_are_put_right_within_frames(turn_in_place):
    """Turning on the spot, the feet touch (frames 36-40) and step apart side by side, 20-25 cm:
    if the labels came out of the touch exchanged (the tracks are exchanged here, so every view
    agrees with the wrong prediction), the legs drawn from the hips to the exchanged feet pass
    through each other, which no body can do; the silhouettes and the limits alone favour the
    right feet by only 2-5 units a frame against a debt of tens from the frames before."""
    at = 46
    _, tj, err, switches, _ = _truth_run(turn_in_place, swap_feet=False, swap_tracks_at=at)
    apart = np.linalg.norm(tj[:, J["foot_l"]] - tj[:, J["foot_r"]], axis=1)
    assert np.all(apart[at:at + 8] > 0.18)                        # side by side, well apart
    assert np.percentile(err[ACQUIRE_FRAMES:at], 95) < 0.03       # right before ...
    assert err[at].min() > 0.1                                    # ... wrong at once ...
    assert np.max(err[at + 4:at + 10]) < 0.03                     # ... and right again within 4 frames


def test_segment_distance_matches_dense_sampling():
    """Closest points of two segments against a brute force over 401 x 401 samples of each,
    including parallel, touching and degenerate (point) segments."""
    rng = np.random.default_rng(4)
    t = np.linspace(0.0, 1.0, 401)[:, None]
    cases = [rng.normal(size=(4, 3)) for _ in range(40)]
    p = rng.normal(size=3)
    cases += [np.array([p, p + [1.0, 0, 0], p + [0, 0.3, 0], p + [2.0, 0.3, 0]]),     # parallel, overlapping
              np.array([p, p + [1.0, 0, 0], p + [0.5, -1, 0], p + [0.5, 1, 0]]),       # crossing: 0
              np.array([p, p, p + [0, 0, 1.0], p + [1.0, 0, 1.0]])]                    # a point
    for p1, q1, p2, q2 in cases:
        a, b = p1 + t * (q1 - p1), p2 + t * (q2 - p2)
        brute = np.min(np.linalg.norm(a[:, None] - b[None], axis=-1))
        assert segment_distance(p1, q1, p2, q2) == pytest.approx(brute, abs=3e-3)
        assert segment_distance(p1, q1, p2, q2) <= brute + 1e-12


def test_true_legs_never_pass_through_each_other_exchanged_ones_do(turn_in_place):
    """Studio truth of the turn on the spot: with the truth's labels the legs (hips -> feet cues)
    never cross (no frame is credited), with the feet exchanged they do in most frames where
    the feet stand apart; with the feet together (touching) neither labelling is credited."""
    rec = Recording(turn_in_place)
    joints, cues = np.asarray(rec.truth["joints"]), np.asarray(rec.truth["cues"])
    rec.close()
    hips = joints[:, [J["hip_l"], J["hip_r"]]]
    right = np.array([crossed_legs_cm2(h, c) for h, c in zip(hips, cues)])
    exchanged = np.array([crossed_legs_cm2(h, swap_pairs(c, ALTERNATIVES.index("feet"))) for h, c in zip(hips, cues)])
    apart = np.linalg.norm(cues[:, FL] - cues[:, FR], axis=1)
    assert np.all(right == 0.0)
    assert np.mean(exchanged[apart > 0.15] > 5.0) > 0.8
    assert np.all(exchanged[apart < 0.05] == 0.0)


def test_skipped_alternatives_are_not_fitted_and_the_rest_are_unchanged():
    """``score_hypotheses(skip=...)``: a skipped alternative's cost is NaN (the caller decides
    it: the feet together, or no views for the mirror), every other cost is the one scored
    without the skip, and the fitter is called once less per skipped alternative."""
    from mocap_rt.fusion.identity import score_hypotheses
    from mocap_rt.geometry.rig import ring_rig

    tracker = BodyTracker(ring_rig())
    cues = tracker.solver.rest_cues + [0.3, -0.2, 0.0]
    cues[FL] += [0.05, 0.1, 0.0]                          # a step: the feet labellings differ
    calls = []
    fit = tracker.solver.fitter.fit
    tracker.solver.fitter.fit = lambda *a, **k: calls.append(1) or fit(*a, **k)
    cfg = tracker.config.identity
    full = score_hypotheses(tracker.solver.fitter, cues, tracker.solver.rest_cues, None, None, cfg)
    n_full = len(calls)
    feet, mirror = ALTERNATIVES.index("feet"), ALTERNATIVES.index("mirror")
    part = score_hypotheses(tracker.solver.fitter, cues, tracker.solver.rest_cues, None, None, cfg, skip=frozenset({feet, mirror}))
    assert len(calls) - n_full == n_full - 2
    assert np.isnan(part[[1 + feet, 1 + mirror]]).all() and np.isfinite(full).all()
    keep = [0, 1 + ALTERNATIVES.index("hands")]
    np.testing.assert_array_equal(part[keep], full[keep])


def test_the_tracker_decides_the_feet_on_the_first_frame_that_tells_them_apart(backwards_walk):
    """A walk with the right labels from the first frame: no feet switch, but the feet are
    decided once a frame has the last pose's hips and the feet wider apart than them (the first
    frame has no pose yet)."""
    rec, truth, names, widths, tracker, rng = _truth_setup(backwards_walk)
    decided, apart = [], []
    for f in range(25):
        tracker.step(f, _truth_cues(truth, names, widths, f, rng, ()))
        decided.append(tracker.identity.feet_decided)
        t = truth["joints"][f]
        apart.append(np.linalg.norm(truth["cues"][f][FL] - truth["cues"][f][FR])
                     > np.linalg.norm(t[J["hip_l"]] - t[J["hip_r"]]))
    rec.close()
    assert tracker.identity.switches == 0 or ALTERNATIVES[tracker.identity.last_switch[0]] == "hands"
    assert not decided[0] and decided[-1]
    first = decided.index(True)
    assert any(apart[max(0, first - 1):first + 1])        # decided where the truth's feet were apart


def test_feet_together_is_closer_than_the_hips():
    """Hand-computed: hips 0.16 m apart; feet 0.14 m apart are together at factor 1 and not at
    0.8 (0.128 m); 0.20 m apart are not; no hips, a missing foot or factor 0: never."""
    hips = np.array([[-0.08, 0.0, 0.9], [0.08, 0.0, 0.9]])
    cues = np.zeros((6, 3))
    cues[FL], cues[FR] = [-0.07, 0.05, 0.1], [0.07, 0.05, 0.1]     # 0.14 m apart, side by side
    assert feet_together(hips, cues, 1.0) and not feet_together(hips, cues, 0.8)
    wide = cues.copy()
    wide[FR, 0] = 0.13                                             # 0.20 m apart
    assert not feet_together(hips, wide, 1.0)
    missing = cues.copy()
    missing[FR] = np.nan
    assert not feet_together(None, cues, 1.0) and not feet_together(hips, missing, 1.0)
    assert not feet_together(hips, cues, 0.0)
    # told apart: hips and both feet known, and not together
    assert feet_told_apart(hips, wide, 1.0) and feet_told_apart(hips, cues, 0.8)
    assert not feet_told_apart(hips, cues, 1.0)
    assert not feet_told_apart(None, wide, 1.0) and not feet_told_apart(hips, missing, 1.0)


@pytest.mark.slow
@pytest.mark.parametrize("legs", [True, False])
def test_a_cold_start_faces_the_way_the_legs_stand_on_the_shoes(hand_behind_head, tmp_path, legs):
    """End to end (rendered images -> perception -> fusion): a person standing with a hand behind
    the head, where a body turned round with its left and right exchanged fits the cues and the
    silhouettes as well. Where the legs meet the shoes (perception.leg_attach) decides the facing
    while the identity is acquired: right from the first frame (measured 9-15 deg heading error).
    Without that term the same start faces the body the wrong way (the control: 150-160 deg)."""
    from mocap_rt.fusion.offline import process_recording

    config = FusionConfig(identity=IdentityConfig(legs_on_shoes_weight=1.0 if legs else 0.0))
    out = process_recording(hand_behind_head, tmp_path, config=config, progress=False)
    rec = Recording(hand_behind_head)
    tj = np.asarray(rec.truth["joints"])[out.frames]
    rec.close()
    joints = np.where(out.joint_valid[..., None], out.joints, np.nan)
    herr = np.abs(wrap_deg(heading_deg(joints) - heading_deg(tj)))
    mir = mirrored_frames(joints, tj)
    if legs:
        assert np.nanmedian(herr) < 30.0 and np.nansum(mir) == 0, (np.round(herr), mir)
    else:
        assert np.nanmedian(herr) > 120.0, np.round(herr)      # the control: this start is the hard case
