"""Node building blocks without processes: schedule, gatherer, grabber, slots, viewer maths, pose log."""

import threading
import time
from dataclasses import replace

import numpy as np
import pytest

from mocap_rt.body.bvh_export import bvh_skeleton_of
from mocap_rt.body.skeleton import BoneLengths, read_bone_lengths
from mocap_rt.cues import CameraCues
from mocap_rt.io.bvh import read_bvh
from nodes.camera_worker import PredictionBox, TriggerQueue
from mocap_rt.fusion.gather import FrameGatherer
from nodes.messages import Cues, Keys, Pose, Trigger
from nodes.monitor import percentiles
from nodes.recorder import PoseFiles, PoseLog, output_paths
from nodes.runtime import NodeRuntime, RateMeter
from nodes.live import Grabber, LiveSource
from nodes.sources import FakeDevice, parse_source
from nodes.sync import Schedule, run_sync
from nodes.viewer import ellipse_points, parse_rerun, skeleton_strips

MS = 1_000_000


# ------------------------------------------------------------------ sync schedule
def test_schedule_is_absolute_and_exact():
    period = round(1e9 / 30)                      # 33_333_333 ns: not exact for 30 fps
    s = Schedule(10_000, period)
    k = 10_000_000                                # ~3.9 days of frames
    assert s.due(k) == 10_000 + k * period        # integer maths: no accumulated error
    # a relative schedule (t += period in float seconds) drifts; the absolute one does not
    t = 10_000 / 1e9
    for _ in range(100_000):
        t += period / 1e9
    assert abs(t * 1e9 - s.due(100_000)) > 0     # float accumulation is off ...
    assert s.due(100_000) - s.due(0) == 100_000 * period   # ... the schedule is exact
    assert s.slot(10_000 + 5 * period - 1) == 4
    assert s.slot(10_000 + 5 * period) == 5
    assert s.slot(0) == 0
    with pytest.raises(ValueError):
        Schedule(0, 0)


class FakePublisher:
    def __init__(self, sink):
        self.sink = sink

    def put(self, payload):
        self.sink.append((time.monotonic_ns(), payload))

    def undeclare(self):
        pass


class FakeSession:
    """Enough of a zenoh.Session for the node loops: publishers record what they put."""

    def __init__(self):
        self.puts: dict[str, list] = {}

    def declare_publisher(self, key, **kw):
        return FakePublisher(self.puts.setdefault(key, []))

    def declare_subscriber(self, key, cb):
        return FakePublisher([])


def test_run_sync_never_triggers_early_and_keeps_ids_tied_to_time():
    sess, keys = FakeSession(), Keys("r")
    rt = NodeRuntime(sess, keys, "sync", "sync")
    t_before = time.monotonic_ns()          # the schedule's t0 is not earlier than this
    sent = run_sync(sess, keys, 200.0, 40, 7, rt)
    puts = sess.puts[keys.trigger]
    assert sent == len(puts) and sent + rt.drops == 40         # 40 slots, triggered or skipped
    trig = [Trigger.from_msgpack(p) for _, p in puts]
    frames = [t.frame for t in trig]
    assert frames[0] == 7 and all(b > a for a, b in zip(frames, frames[1:]))
    period = round(1e9 / 200)
    assert all(t.period_ns == period for t in trig)
    # frame k is never sent before its slot t0 + (k - 7) * period (absolute schedule)
    assert all(t.t_mono_ns >= t_before + (t.frame - 7) * period for t in trig)
    # skipped slots (a late process) are counted: the gaps between the ids are skipped slots, and
    # so may be the last slots (``frames`` bounds the slots, triggered or skipped)
    assert frames[-1] <= 7 + 40 - 1
    assert frames[-1] - 7 + 1 - sent <= rt.drops


class StallingPublisher(FakePublisher):
    """A put that stalls the sync process for 2.5 periods every 10th trigger."""

    def __init__(self, sink, stall_s):
        super().__init__(sink)
        self.stall_s = stall_s

    def put(self, payload):
        super().put(payload)
        if len(self.sink) % 10 == 0:
            time.sleep(self.stall_s)


def test_run_sync_frames_bound_the_slots_when_the_process_falls_behind():
    """``--frames N``: the ids stay within start .. start + N - 1 even when slots are skipped
    (a replay of N frames is one pass, never a wrap to frame 0), and triggers + skipped = N."""
    sess, keys = FakeSession(), Keys("r")
    fps, n, start = 200.0, 40, 100
    sess.declare_publisher = lambda key, **kw: StallingPublisher(sess.puts.setdefault(key, []), 2.5 / fps)
    rt = NodeRuntime(sess, keys, "sync", "sync")
    sent = run_sync(sess, keys, fps, n, start, rt)
    frames = [Trigger.from_msgpack(p).frame for _, p in sess.puts[keys.trigger]]
    assert rt.drops >= 3, rt.drops                   # every stall skipped at least one slot
    assert sent == len(frames) and sent + rt.drops == n
    assert frames == sorted(set(frames)) and set(frames) <= set(range(start, start + n)), frames


# ------------------------------------------------------------------ fusion gathering
def _cues(cam, frame, t_trig):
    return Cues("r", CameraCues.empty(cam, frame), t_trig, t_trig, 1.0)


def test_gatherer_waits_for_live_cameras_then_deadline():
    g = FrameGatherer(["a", "b", "c"], deadline_frac=0.5, liveness_s=0.1)
    period = 40 * MS
    g.on_trigger(Trigger("r", 0, 1000 * MS, 0, period), now_ns=1000 * MS)
    now = 1001 * MS
    for cam in "abc":
        g.on_cues(_cues(cam, 0, 1000 * MS), now)
    ready = g.ready(now)                                  # all three live cameras answered
    assert [pf.frame for pf in ready] == [0] and set(ready[0].cues) == {"a", "b", "c"}
    # frame 1: only a and b answer; c is still live -> wait ...
    g.on_trigger(Trigger("r", 1, 1040 * MS, 0, period), now_ns=1040 * MS)
    g.on_cues(_cues("a", 1, 1040 * MS), 1041 * MS)
    g.on_cues(_cues("b", 1, 1040 * MS), 1041 * MS)
    assert g.ready(1042 * MS) == []
    # ... until the deadline t_trigger + 0.5 * period (answers on time: counted from the trigger)
    assert g.next_deadline_ns() == 1060 * MS
    ready = g.ready(1060 * MS)
    assert [pf.frame for pf in ready] == [1] and set(ready[0].cues) == {"a", "b"}
    # c's late answer is counted, not used
    g.on_cues(_cues("c", 1, 1040 * MS), 1061 * MS)
    assert g.late_cues == 1
    # once c has been silent longer than liveness, frames complete without waiting for it
    g.on_trigger(Trigger("r", 2, 1200 * MS, 0, period), now_ns=1200 * MS)
    g.on_cues(_cues("a", 2, 1200 * MS), 1201 * MS)
    g.on_cues(_cues("b", 2, 1200 * MS), 1201 * MS)
    assert [pf.frame for pf in g.ready(1201 * MS)] == [2]
    assert g.live(1201 * MS) == {"a", "b"}


def test_gatherer_drops_empty_frames_and_overtaken_frames():
    g = FrameGatherer(["a"], deadline_frac=0.5, liveness_s=1.0)
    period = 10 * MS
    g.on_trigger(Trigger("r", 0, 0, 0, period), now_ns=0)          # nobody answers frame 0
    g.on_trigger(Trigger("r", 1, 10 * MS, 0, period), now_ns=10 * MS)
    g.on_cues(_cues("a", 1, 10 * MS), 11 * MS)
    ready = g.ready(11 * MS)
    assert [pf.frame for pf in ready] == [1]              # frame 0 (no cues) overtaken
    assert g.frames_dropped == 1
    g.on_cues(_cues("a", 0, 0), 12 * MS)                   # too late for frame 0
    assert g.late_cues == 1
    g.on_cues(_cues("zzz", 2, 0), 12 * MS)                 # not a rig camera: ignored
    assert 2 not in g.pending


# ------------------------------------------------------------------ grabber / fake device
def _pattern(i: int) -> np.ndarray:
    img = np.zeros((8, 8, 3), np.uint8)
    img[0, 0] = [i % 256, (i // 256) % 256, 7]
    return img


def test_grabber_serves_the_newest_frame_of_a_real_time_device():
    dev = FakeDevice(_pattern, fps=200.0)
    grab = Grabber(dev)
    try:
        g0 = grab.latest()
        seqs, stamps = [g0.seq], [g0.t_mono_ns]
        for _ in range(5):
            time.sleep(0.03)                               # a slow consumer: ~6 device frames pass
            g = grab.latest(after_seq=seqs[-1])
            # the image is the one the device made for that sequence number
            assert g.image[0, 0, 0] == g.seq % 256 and g.image[0, 0, 1] == (g.seq // 256) % 256
            seqs.append(g.seq)
            stamps.append(g.t_mono_ns)
        assert all(b > a for a, b in zip(seqs, seqs[1:]))
        assert all(b > a for a, b in zip(stamps, stamps[1:]))
        # frames were skipped (only the newest is kept) and counted as overwritten
        assert seqs[-1] - seqs[0] > len(seqs)
        assert grab.overwritten >= seqs[-1] - seqs[0] - len(seqs)
    finally:
        grab.close()


def test_live_source_backgrounds_are_distinct_consecutive_frames():
    src = LiveSource(FakeDevice(_pattern, fps=300.0), "cam", n_backgrounds=4)
    try:
        bg = src.backgrounds()
        assert bg.shape == (4, 8, 8, 3)
        ids = [int(b[0, 0, 0]) + 256 * int(b[0, 0, 1]) for b in bg]
        assert len(set(ids)) == 4 and ids == sorted(ids)
        g = src.grab(123)
        assert g.seq >= ids[-1]                             # the newest frame, never an older one
    finally:
        src.close()


def test_grabber_times_out_without_frames():
    class Dead:
        def read(self):
            time.sleep(0.01)
            return False, None

        def release(self):
            pass

    grab = Grabber(Dead())
    try:
        with pytest.raises(TimeoutError):
            grab.latest(timeout_s=0.1)
        assert grab.failures > 0
    finally:
        grab.close()


def test_parse_source():
    assert parse_source("replay:/x/y") == ("replay", "/x/y")
    assert parse_source("v4l2:/dev/video0") == ("v4l2", "/dev/video0")
    for bad in ("replay:", "usb:/dev/x", "/dev/video0"):
        with pytest.raises(ValueError):
            parse_source(bad)


# ------------------------------------------------------------------ worker slots
def test_trigger_queue_keeps_the_newest_and_counts_overwritten():
    slot = TriggerQueue()
    for f in range(5):
        slot.put(Trigger("r", f, f, f, 1))
    assert slot.take(0.01).frame == 4
    assert slot.overwritten == 4
    assert slot.take(0.01) is None
    deep = TriggerQueue(depth=3)                 # a replay worker: catches up, oldest first
    for f in range(5):
        deep.put(Trigger("r", f, f, f, 1), recv_ns=100 + f)
    assert [(deep.take(0.01).frame, deep.taken_recv_ns) for _ in range(3)] == [(2, 102), (3, 103), (4, 104)]
    assert deep.overwritten == 2 and deep.take(0.01) is None
    th = threading.Timer(0.05, lambda: slot.put(Trigger("r", 9, 9, 9, 1)))
    th.start()
    assert slot.take(2.0).frame == 9


def test_prediction_box_keeps_recent_frames():
    from mocap_rt.cues import CuePrediction
    box = PredictionBox()
    for f in range(20):
        box.put(CuePrediction("c", f, np.zeros((6, 2)), np.ones(6, bool), np.ones(6)))
    assert box.get(19).frame == 19 and box.get(0) is None


# ------------------------------------------------------------------ small helpers
def test_rate_meter_counts_over_window():
    m = RateMeter(window_s=1.0)
    for i in range(11):
        m.add(2.0 + i, now=100.0 + 0.1 * i)                # 10 intervals in 1 s
    assert m.fps(now=101.0) == pytest.approx(10.0)
    assert m.median_ms() == pytest.approx(7.0)
    assert m.fps(now=105.0) == 0.0                         # all out of the window


def test_percentiles_match_numpy():
    v = np.random.default_rng(1).exponential(5.0, 1000)
    p = percentiles(v)
    assert p["p99"] == pytest.approx(np.percentile(v, 99)) and p["max"] == v.max()
    assert np.isnan(percentiles([])["p50"])


def test_ellipse_points_lie_on_the_sigma_contour():
    rng = np.random.default_rng(0)
    for _ in range(20):
        A = rng.normal(size=(2, 2))
        cov = A @ A.T + 0.1 * np.eye(2)
        c = rng.normal(size=2) * 100
        pts = ellipse_points(c, cov, sigma=2.0)
        d = pts - c
        m = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d)   # Mahalanobis^2
        np.testing.assert_allclose(m, 4.0, rtol=1e-9)
        np.testing.assert_allclose(pts[0], pts[-1])              # closed


def test_skeleton_strips_follow_the_joint_order():
    from mocap_rt.names import JOINT_NAMES
    J = np.arange(60, dtype=float).reshape(20, 3)
    strips = skeleton_strips(J)
    assert len(strips) == 5
    np.testing.assert_array_equal(strips[0][0], J[JOINT_NAMES.index("pelvis")])
    np.testing.assert_array_equal(strips[0][-1], J[JOINT_NAMES.index("head")])
    J[JOINT_NAMES.index("knee_l")] = np.nan
    assert len(skeleton_strips(J)) == 4


def test_parse_rerun_specs():
    assert parse_rerun("save:out/x.rrd") == ("save", ["out/x.rrd"])
    assert parse_rerun("serve") == ("serve", [])
    assert parse_rerun("serve:9000:9001") == ("serve", ["9000", "9001"])
    assert parse_rerun("spawn") == ("spawn", [])
    for bad in ("save:", "serve:x", "web", "spawn:1"):
        with pytest.raises(ValueError):
            parse_rerun(bad)


def test_pose_log_snapshot_round_trip(tmp_path):
    log = PoseLog(tmp_path / "poses.npz", ["a", "b"])
    rng = np.random.default_rng(0)
    poses = [Pose("r", f, 10 * MS * f, 10 * MS * f + 3 * MS, rng.normal(size=(6, 3)), np.ones(6, bool),
                  rng.normal(size=(20, 3)), rng.normal(size=12), ("a",), ("b",), BoneLengths().as_array())
             for f in range(5)]
    for p in poses:
        log.add(p)
    log.snapshot()
    d = np.load(tmp_path / "poses.npz")
    np.testing.assert_array_equal(d["frames"], np.arange(5))
    np.testing.assert_array_equal(d["joints"], np.stack([p.joints for p in poses]))
    np.testing.assert_array_equal(d["bvh_motion"], np.stack([p.bvh_frame for p in poses]))
    np.testing.assert_array_equal(d["cameras_used"], [[True, False]] * 5)
    np.testing.assert_allclose(d["latency_ms"], 3.0)
    assert list(d["camera_names"]) == ["a", "b"]
    assert not (tmp_path / "poses.tmp.npz").exists()


def test_output_paths_never_reuse_existing_files(tmp_path):
    a = output_paths(tmp_path)
    assert a[0].name == "poses.npz"
    a[1].write_text("x")
    b = output_paths(tmp_path)
    assert [p.name for p in b] == ["poses_001.npz", "poses_001.bvh", "bones_001.toml", "stream_001"]


def _pose(frame: int, bones: BoneLengths, n_channels: int) -> Pose:
    rng = np.random.default_rng(frame)
    return Pose("r", frame, 0, 1, np.zeros((6, 3)), np.ones(6, bool), np.zeros((20, 3)),
                rng.uniform(-90, 90, n_channels), ("a",), (), bones.as_array())


def test_pose_files_give_the_bvh_the_calibrated_skeleton(tmp_path):
    default, subject = BoneLengths(), BoneLengths().scaled(1.1)
    n_ch = bvh_skeleton_of(default).n_channels
    files = PoseFiles(tmp_path / "p.npz", tmp_path / "p.bvh", tmp_path / "b.toml", ["a"], 30.0)
    sent = [_pose(f, default, n_ch) for f in range(40)] + [_pose(f, subject, n_ch) for f in range(40, 75)]
    for p in sent[:40]:
        files.add(p)
    assert read_bone_lengths(tmp_path / "b.toml") == default
    for p in sent[40:]:
        files.add(p)
    with pytest.raises(ValueError, match="not newer"):
        files.add(_pose(10, subject, n_ch))
    with pytest.raises(ValueError, match="bone length"):
        files.add(replace(_pose(80, subject, n_ch), bones=-subject.as_array()))
    files.close()
    clip = read_bvh(tmp_path / "p.bvh")
    np.testing.assert_allclose(clip.skeleton.offsets, bvh_skeleton_of(subject).offsets, atol=1e-6)
    np.testing.assert_allclose(clip.skeleton.offsets, 1.1 * bvh_skeleton_of(default).offsets, atol=1e-6)
    np.testing.assert_allclose(clip.motion, [p.bvh_frame for p in sent], atol=1e-4)
    assert read_bone_lengths(tmp_path / "b.toml") == subject
    np.testing.assert_array_equal(np.load(tmp_path / "p.npz")["frames"], np.arange(75))


def test_gatherer_first_frames_wait_for_every_rig_camera():
    g = FrameGatherer(["a", "b"], deadline_frac=0.5, liveness_s=0.5)
    g.on_trigger(Trigger("r", 0, 0, 0, 40 * MS), now_ns=0)     # the first trigger: all presumed live
    g.on_cues(_cues("a", 0, 0), 1 * MS)
    assert g.ready(2 * MS) == []                       # b is presumed live: wait for it
    g.on_cues(_cues("b", 0, 0), 3 * MS)
    assert set(g.ready(3 * MS)[0].cues) == {"a", "b"}


def test_gatherer_fuses_an_older_partial_frame_before_a_newer_complete_one():
    g = FrameGatherer(["a", "b"], deadline_frac=0.8, liveness_s=1.0)
    g.assume_all_live(0)
    g.on_trigger(Trigger("r", 5, 0, 0, 40 * MS), now_ns=0)
    g.on_trigger(Trigger("r", 6, 40 * MS, 0, 40 * MS), now_ns=40 * MS)
    g.on_cues(_cues("a", 5, 0), 41 * MS)          # frame 5: only a so far (deadline 32 ms ...
    g.on_cues(_cues("a", 6, 40 * MS), 41 * MS)
    g.on_cues(_cues("b", 6, 40 * MS), 41 * MS)     # ... frame 6 complete
    out = g.ready(41 * MS)
    assert [pf.frame for pf in out] == [5, 6] and set(out[0].cues) == {"a"}
    assert g.frames_dropped == 0
    # a frame without any answer waits past its deadline for a late one
    g.on_trigger(Trigger("r", 7, 80 * MS, 0, 40 * MS), now_ns=80 * MS)
    assert g.ready(200 * MS) == [] and g.next_deadline_ns() is None
    g.on_cues(_cues("b", 7, 80 * MS), 201 * MS)
    # ... and then waits for the others the usual 32 ms, counted from that answer
    assert g.ready(201 * MS) == [] and g.next_deadline_ns() == 233 * MS
    assert [pf.frame for pf in g.ready(233 * MS)] == [7]


def test_gatherer_waits_for_every_camera_of_a_frame_served_after_a_stall():
    """Every camera stalled and then catches up (the workers keep a few triggers): the
    frames they missed arrive late, in order, and each is fused whole, none dropped."""
    cams = list("abcdef")
    g = FrameGatherer(cams, deadline_frac=0.8, liveness_s=0.25)
    period = 33 * MS
    g.on_trigger(Trigger("r", 0, 0, 0, period), now_ns=0)
    for c in cams:
        g.on_cues(_cues(c, 0, 0), 5 * MS)
    assert [pf.frame for pf in g.ready(5 * MS)] == [0]
    # a 70 ms stall: triggers 1 and 2 arrive, nobody answers until 75 ms
    g.on_trigger(Trigger("r", 1, 33 * MS, 0, period), now_ns=33 * MS)
    g.on_trigger(Trigger("r", 2, 66 * MS, 0, period), now_ns=66 * MS)
    fused = []
    t = 75 * MS
    for frame in (1, 2):                        # the cameras take turns on 2 cores
        for c in cams:
            g.on_cues(_cues(c, frame, frame * period), t)
            fused += g.ready(t)
            t += 2 * MS
    assert [pf.frame for pf in fused] == [1, 2]
    assert all(set(pf.cues) == set(cams) for pf in fused)
    assert g.frames_dropped == 0 and g.late_cues == 0


def test_gatherer_first_frame_has_a_grace_period():
    from nodes.fusion_node import FIRST_FRAME_GRACE_S
    g = FrameGatherer(["a", "b"], deadline_frac=0.5, liveness_s=2.0)
    g.on_trigger(Trigger("r", 0, 0, 0, 40 * MS), now_ns=0)
    g.on_cues(_cues("a", 0, 0), 1 * MS)
    assert g.ready(30 * MS) == []                                   # past the usual 20 ms deadline
    assert g.next_deadline_ns() == int(FIRST_FRAME_GRACE_S * 1e9)
    g.on_cues(_cues("b", 0, 0), 45 * MS)                             # a slow first frame of b
    assert set(g.ready(45 * MS)[0].cues) == {"a", "b"}
    g.on_trigger(Trigger("r", 1, 40 * MS, 0, 40 * MS), now_ns=40 * MS)
    assert g.pending[1].deadline_ns == 40 * MS + 20 * MS             # later frames: the usual deadline


def test_demo_summary_names_the_cameras_most_often_missing():
    from nodes.demo import _most_missing

    counts = {"cam_1": 0, "cam_2": 5, "cam_3": 12, "cam_4": 1, "cam_5": 4, "cam_6": 0}
    assert _most_missing(counts) == "; late or missing: cam_3 12, cam_2 5, cam_5 4"
    assert _most_missing({"cam_1": 0, "cam_2": 0}) == ""


# ------------------------------------------------------------------ monitor
def test_run_stats_reads_the_monitor_while_poses_arrive():
    """The transport's threads append poses while a report counts them: ``run_stats`` reads a
    copy taken under the monitor's lock (it iterated the live deque, and a fault test met
    'deque mutated during iteration')."""
    from types import SimpleNamespace

    from nodes.monitor import PoseEvent, ServiceMonitor
    from nodes.run_report import run_stats

    class Session:
        def declare_subscriber(self, key, cb):
            return None

    mon = ServiceMonitor(Session(), Keys("r"))
    launcher = SimpleNamespace(monitor=mon, nodes={}, cpu_at_start={}, rig_name="r", trigger_fps=30.0,
                               cfg=SimpleNamespace(source="replay:x", speed=1.0),
                               rig=SimpleNamespace(names=("cam_1", "cam_2")), log_dir="/tmp")
    stop = threading.Event()

    def feed():
        for f in range(200_000):
            if stop.is_set():
                break
            with mon._lock:                        # as ServiceMonitor._ingest appends
                mon.triggers[f] = f * 33 * MS
                mon.poses.append(PoseEvent(f, f * 33 * MS, f * 33 * MS + 10 * MS, f * 33 * MS + 11 * MS,
                                           ("cam_1",), ("cam_2",)))
            time.sleep(0)                          # let the reader take the lock

    import sys

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)                    # threads switch often: the race shows at once
    t = threading.Thread(target=feed)
    t.start()
    try:
        for _ in range(50):
            stats = run_stats(launcher)
            assert stats["poses_missing_camera"]["cam_2"] == stats["poses_with_missing_cameras"]
    finally:
        stop.set()
        t.join()
        sys.setswitchinterval(interval)
    assert stats["poses_with_missing_cameras"] > 0


def test_slowest_poses_lists_the_top_percent_slowest_first():
    """``slowest_poses``: the slowest 1 % (at least 5) by trigger -> published, with their
    frames and stage timings, so a p99 can be traced to its frames."""
    from nodes.monitor import PoseEvent
    from nodes.run_report import slowest_poses

    lat_ms = [(f * 37) % 1000 / 10 for f in range(1000)]           # 0.0 .. 99.9, each once
    events = [PoseEvent(f, 0, int(lat_ms[f] * MS), 0, (), (), {"step_ms": float(f)}) for f in range(1000)]
    got = slowest_poses(events)
    assert [r["latency_ms"] for r in got] == [99.9, 99.8, 99.7, 99.6, 99.5, 99.4, 99.3, 99.2, 99.1, 99.0]
    for r in got:
        assert lat_ms[r["frame"]] == r["latency_ms"] and r["step_ms"] == r["frame"]
    assert len(slowest_poses(events[:20])) == 5
    assert slowest_poses([]) == []
