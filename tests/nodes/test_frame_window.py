"""FrameWindow: the frames each node accepts messages for (no processes, no Zenoh).

Hand-made cases for each rule, and hypothesis properties that throw arbitrary frame numbers,
timestamps and rig names, through the wire format, at the accept logic of every node role.
"""

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mocap_rt.cues import N_CUES, CameraCues, CuePrediction
from nodes.frame_window import (RECORD_AHEAD, RECORD_BEHIND, REANCHOR_TRIGGERS, WINDOW_AHEAD, WINDOW_BEHIND, FrameWindow,
                                window_drops)
from nodes.messages import Cues, Decoder, Pose, Prediction, Trigger

RIG = "studio"
PERIOD = 33_333_333
T0 = 5_000_000_000
CAMS = ("cam_1", "cam_2", "cam_3")
MAX_FRAME = 2**63 - 1

# the message types each node role receives (and feeds through its FrameWindow)
ROLES = {"fusion": (Cues,), "recorder": (Pose,), "camera": (Prediction,), "viewer": (Cues, Pose), "streamer": (Pose,),
         "monitor": (Pose,)}


def trig(frame, t=None, rig=RIG, period=PERIOD):
    return Trigger(rig, frame, T0 + frame * PERIOD if t is None else t, 0, period)


def cues(frame, t_trig, cam="cam_1", rig=RIG):
    c = CameraCues(cam, frame, np.zeros((N_CUES, 2)), np.tile(np.eye(2), (N_CUES, 1, 1)),
                   np.ones(N_CUES), np.ones(N_CUES))
    return Cues(rig, c, t_trig, t_trig, 1.0)


def pose(frame, t_trig, rig=RIG):
    from mocap_rt.body.skeleton import BoneLengths
    from mocap_rt.names import JOINT_NAMES

    return Pose(rig, frame, t_trig, t_trig + 1, np.zeros((N_CUES, 3)), np.ones(N_CUES, bool),
                np.zeros((len(JOINT_NAMES), 3)), np.zeros(3), CAMS, (), BoneLengths().as_array(), {})


def pred(frame, cam="cam_1", rig=RIG):
    return Prediction(rig, CuePrediction(cam, frame, np.zeros((N_CUES, 2)), np.ones(N_CUES, bool),
                                         np.full(N_CUES, 9.0)))


def make(cls, frame, t_trig, rig=RIG):
    return pred(frame, rig=rig) if cls is Prediction else (cues if cls is Cues else pose)(frame, t_trig, rig=rig)


def wire(msg):
    """Through msgpack and the nodes' Decoder, as on the bus (None if the decoder drops it)."""
    return Decoder("test").decode(msg.to_msgpack(), type(msg))


# ------------------------------------------------------------------ hand-made cases
def test_the_two_attacks_of_issue_14_are_dropped_and_counted():
    w = FrameWindow(RIG)
    for f in range(10):
        assert w.accept(trig(f)) == [trig(f)]
        assert w.accept(cues(f, trig(f).t_mono_ns)) != []
    assert w.accept(cues(2**62, trig(9).t_mono_ns)) == []            # attack 1
    assert all(w.accept(pose(100_000 + i, trig(9).t_mono_ns)) == [] for i in range(300))   # attack 2
    assert w.drops["future"] == 301 and w.total_drops == 301
    # the service goes on: the next frames are accepted
    for f in range(10, 20):
        assert w.accept(trig(f)) and w.accept(pose(f, trig(f).t_mono_ns))


def test_the_recorder_window_keeps_a_pose_delayed_by_a_busy_host():
    """A starved recorder / monitor sees a pose after 100 newer triggers, or 100 frames before its
    trigger: live consumers drop it (stale, future), the recorder keeps it (it names a triggered frame and carries its stamp); a pose older
    than the recorder's own bound, or of a frame never triggered, is still dropped."""
    live, rec = FrameWindow(RIG), FrameWindow(RIG, behind=RECORD_BEHIND, ahead=RECORD_AHEAD)
    for f in range(RECORD_BEHIND + 150):
        live.accept(trig(f))
        rec.accept(trig(f))
    late = RECORD_BEHIND + 49 - 100
    assert live.accept(pose(late, trig(late).t_mono_ns)) == [] and live.drops["stale"] == 1
    assert rec.accept(pose(late, trig(late).t_mono_ns)) != []
    assert rec.accept(pose(10, trig(10).t_mono_ns)) == [] and rec.drops["stale"] == 1
    assert rec.accept(pose(late, trig(late).t_mono_ns + 1)) == [] and rec.drops["stamp"] == 1
    # ... and a pose seen 100 frames before its trigger: held, recorded when the trigger comes
    now = rec.current
    early = pose(now + 100, trig(now + 100).t_mono_ns)
    assert live.accept(early) == [] and live.drops["future"] == 1
    assert rec.accept(early) == [] and rec.drops["future"] == 0
    for f in range(now + 1, now + 100):
        assert rec.accept(trig(f)) == [trig(f)]
    assert rec.accept(trig(now + 100)) == [trig(now + 100), early]
    assert rec.accept(pose(rec.current + RECORD_AHEAD + 1, 0)) == [] and rec.drops["future"] == 1


def test_each_reason():
    w = FrameWindow(RIG)
    for f in range(40):
        w.accept(trig(f))
    t = trig(39).t_mono_ns
    assert w.accept(cues(39, t, rig="other")) == [] and w.drops["rig"] == 1
    assert w.accept(cues(39, t + 1)) == [] and w.drops["stamp"] == 1          # not its trigger's time
    assert w.accept(cues(39 - WINDOW_BEHIND - 1, trig(39 - WINDOW_BEHIND - 1).t_mono_ns)) == []
    assert w.drops["stale"] == 1
    assert w.accept(cues(39 + WINDOW_AHEAD + 1, t)) == [] and w.drops["future"] == 1
    assert w.accept(pred(39 + WINDOW_AHEAD)) and not w.accept(pred(39 + WINDOW_AHEAD + 1))
    # a skipped slot: frame 41 never triggered (the sync jumped 40 -> 42)
    w.accept(trig(40))
    held = cues(41, trig(41).t_mono_ns)
    assert w.accept(held) == []                        # held: its trigger may be on its way
    assert w.accept(trig(42)) == [trig(42)]            # ... it never came
    assert w.drops["unknown"] == 1
    assert w.counters()["window_unknown"] == 1


def test_cues_before_their_trigger_are_held_and_released_with_it():
    w = FrameWindow(RIG)
    w.accept(trig(0))
    early = cues(1, trig(1).t_mono_ns)
    assert w.accept(early, "item") == []
    assert w.accept(trig(1)) == [trig(1), "item"]
    assert w.total_drops == 0
    # held before the very first trigger too (a node that starts mid-stream)
    w2 = FrameWindow(RIG)
    assert w2.accept(cues(7, trig(7).t_mono_ns), "seven") == []
    assert w2.accept(trig(7)) == [trig(7), "seven"]


def test_triggers_must_fit_the_previous_one_and_a_restarted_sync_re_anchors():
    w = FrameWindow(RIG)
    for f in range(5):
        w.accept(trig(f))
    assert w.accept(trig(2**62, t=trig(5).t_mono_ns)) == []          # a frame far ahead
    assert w.accept(trig(9, t=trig(5).t_mono_ns)) == []              # frame 9 at frame 5's time
    assert w.accept(trig(3)) == [] and w.drops["trigger"] == 3       # going back
    assert w.accept(trig(8)) == [trig(8)]                            # the sync skipped 5..7 (it was late)
    late = trig(9, t=trig(9).t_mono_ns + 40 * PERIOD)                # sent 40 periods late (descheduled)
    assert w.accept(late) == [late]
    skip = trig(50, t=late.t_mono_ns + PERIOD // 10)                # ... then skipped to the slot it is in
    assert w.accept(skip) == [skip]
    assert w.accept(trig(60, t=T0 + 56 * PERIOD)) == []             # 4 periods before its slot: refused
    # the sync restarts at frame 0 with a new clock: re-anchored after REANCHOR_TRIGGERS triggers
    t_new = T0 + 10**12
    got = [w.accept(trig(f, t=t_new + f * PERIOD)) for f in range(REANCHOR_TRIGGERS + 2)]
    assert [bool(g) for g in got] == [False] * (REANCHOR_TRIGGERS - 1) + [True] * 3
    assert w.current == REANCHOR_TRIGGERS + 1


def test_window_drops_sums_nodes_and_windows():
    w = FrameWindow(RIG)
    w.accept(cues(1, 1, rig="x"))
    table = {"fusion": {"x_window_future": 2}, "recorder": {"x_window_future": 1, "x_window_stale": 4}}
    d = window_drops(table, w)
    assert d["future"] == 3 and d["stale"] == 4 and d["rig"] == 1 and d["stamp"] == 0


# ------------------------------------------------------------------ properties
frames = st.one_of(st.integers(0, 200), st.integers(0, MAX_FRAME), st.sampled_from([2**62, MAX_FRAME]))
stamps = st.integers(-(2**63), 2**63 - 1)
rigs = st.one_of(st.just(RIG), st.text(alphabet="abcdefghijklmnopqrstuvwxyz_0123456789", min_size=1,
                                       max_size=12))
forged = st.tuples(st.sampled_from(["trigger", "msg"]), frames, stamps, rigs)


def _genuine_stream(n: int, skips: list[int], cls, early: list[bool]):
    """The sync's triggers (with skipped slots) and one message per triggered frame, the
    message sometimes arriving before its trigger (another link)."""
    out, f = [], 0
    for i in range(n):
        f += 1 + (skips[i % len(skips)] if skips else 0)
        t = trig(f)
        m = make(cls, f + 1 if cls is Prediction else f, t.t_mono_ns)
        out += [("genuine", m), ("genuine", t)] if early[i % len(early)] and cls is not Prediction \
            else [("genuine", t), ("genuine", m)]
    return out


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(role=st.sampled_from(sorted(ROLES)), garbage=st.lists(forged, max_size=40),
       before=st.lists(forged, max_size=10), n=st.integers(REANCHOR_TRIGGERS + 2, 30),
       skips=st.lists(st.integers(0, 2), max_size=5), early=st.lists(st.booleans(), min_size=1, max_size=5),
       data=st.data())
def test_property_arbitrary_messages_never_displace_the_genuine_stream(role, garbage, before, n, skips, early,
                                                                      data):
    """Any garbage before the sync starts (triggers included), then the genuine stream with
    arbitrary cues / poses / predictions mixed in: from the REANCHOR_TRIGGERS-th genuine
    trigger on, every genuine message is accepted exactly once, and a forged message is
    accepted only if it names a triggered frame with its trigger's stamp (poses, cues) or a
    frame inside the window (predictions)."""
    w = FrameWindow(RIG, role)
    classes = ROLES[role]
    cls = data.draw(st.sampled_from(classes))

    def forged_msg(kind, frame, stamp, rig):
        if kind == "trigger":
            return trig(frame, t=max(0, stamp), rig=rig)
        return make(data.draw(st.sampled_from(classes)), frame, max(0, stamp), rig=rig)

    genuine = _genuine_stream(n, skips, cls, early)
    mixed = list(genuine)
    for g in garbage:
        if g[0] == "msg":
            mixed.insert(data.draw(st.integers(0, len(mixed))), ("forged", forged_msg(*g)))
    events = [("forged", forged_msg(*g)) for g in before] + mixed
    accepted = []
    triggered: dict[int, int] = {}
    for origin, msg in events:
        m = wire(msg)
        if m is None:
            continue
        for item in w.accept(m, (origin, m)):
            accepted.append(item)
            if isinstance(item[1], Trigger):
                triggered[item[1].frame] = item[1].t_mono_ns
            elif isinstance(item[1], Prediction):
                assert w.current - WINDOW_BEHIND <= item[1].prediction.frame <= w.current + WINDOW_AHEAD
            else:   # cues / pose: a triggered frame, with that trigger's stamp, in the window
                assert triggered.get(item[1].frame) == item[1].t_trigger_mono_ns
                assert item[1].frame >= w.current - WINDOW_BEHIND and item[1].rig == RIG
    got = [_key(m) for o, m in accepted if o == "genuine"]
    gen_trig = [m for o, m in genuine if isinstance(m, Trigger)]
    sure = gen_trig[REANCHOR_TRIGGERS - 1:]              # re-anchored by then, whatever came before
    first = sure[0].frame
    assert all(_key(t) in got for t in sure)
    want = [_key(m) for o, m in genuine if not isinstance(m, Trigger) and _key(m)[1] > first]
    for k in want:
        assert got.count(k) == 1, (k, w.drops)
    # conservation: every non-trigger message was accepted, dropped (counted) or is still held
    n_msgs = sum(1 for _, m in events if not isinstance(m, Trigger) and wire(m) is not None)
    n_acc = sum(1 for _, m in accepted if not isinstance(m, Trigger))
    assert n_acc + w.total_drops - w.drops["trigger"] - _rig_triggers(w, events) + len(w._held) == n_msgs


def _key(m) -> tuple[str, int]:
    """(type, the frame a message belongs to): a prediction belongs to the frame before it."""
    return (m.TYPE, m.prediction.frame - 1 if isinstance(m, Prediction) else m.frame)


def _rig_triggers(w, events) -> int:
    """Triggers dropped for their rig name (counted under "rig" with the messages)."""
    return sum(1 for _, m in events if isinstance(m, Trigger) and m.rig != RIG and wire(m) is not None)


@settings(max_examples=40, deadline=None)
@given(frame=st.integers(-(2**70), 2**70), stamp=st.integers(-(2**70), 2**70))
def test_property_out_of_range_numbers_never_reach_a_window(frame, stamp):
    """Frames or stamps outside int64 / negative ones are the decoder's drops, never an exception."""
    w = FrameWindow(RIG)
    w.accept(trig(3))
    for msg in (replace(trig(3), frame=frame, t_mono_ns=stamp), pose(frame, stamp)):
        try:
            payload = msg.to_msgpack()
        except (OverflowError, ValueError):
            continue                     # msgpack cannot even carry it
        m = Decoder("t").decode(payload, type(msg))
        in_int64 = 0 <= frame < 2**63 and 0 <= stamp < 2**63
        assert (m is not None) == in_int64
        if m is not None:
            w.accept(m)
    assert w.current in (3, frame)
    assert w.accepted <= 1 and (w.accepted == 0 or frame == 3 or w.current == frame)


@pytest.mark.parametrize("role", sorted(ROLES))
def test_every_role_keeps_a_clean_stream_whole(role):
    w = FrameWindow(RIG, role)
    n = 0
    for f in range(200):
        assert w.accept(wire(trig(f)))
        for cls in ROLES[role]:
            m = wire(make(cls, f + (cls is Prediction), trig(f).t_mono_ns))
            n += len(w.accept(m))
    assert n == 200 * len(ROLES[role]) and w.total_drops == 0
