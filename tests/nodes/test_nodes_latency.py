"""The latency measures of the service: stage timings, publish order, GC between frames,
real-time scheduling and priorities (no Zenoh: fakes for publishers and tracker)."""

import gc
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mocap_rt.body.skeleton import BoneLengths
from mocap_rt.cues import CameraCues, CuePrediction
from nodes.fusion_node import PendingFrame, fuse_and_publish, stage_timings
from nodes.messages import Keys, Pose, Prediction
from nodes.runtime import IdleGC

MS = 1_000_000
REPO = Path(__file__).resolve().parents[2]


def _cues(cam: str, frame: int, timings: dict) -> CameraCues:
    return CameraCues(cam, frame, np.zeros((6, 2)), np.tile(np.eye(2), (6, 1, 1)), np.ones(6), np.ones(6),
                      (0, 0, 10, 10), dict(timings))


def test_stage_timings_report_the_slowest_and_fastest_camera():
    pf = PendingFrame(7, t_trigger_mono_ns=1000 * MS, deadline_ns=0)
    pf.cues = {"a": _cues("a", 7, {"total": 2.0, "w_recv": 0.5, "w_start": 0.6, "w_pub": 3.0, "w_cpu": 2.1}),
               "b": _cues("b", 7, {"total": 3.5, "w_recv": 4.0, "w_start": 4.2, "w_pub": 8.5, "w_cpu": 3.6}),
               "c": _cues("c", 7, {"total": 1.0})}          # an old worker: no w_* stamps
    pf.t_first_ns, pf.t_last_ns = 1004 * MS, 1009 * MS
    st = stage_timings(pf, t_ready_ns=1010 * MS)
    assert st["w_recv"] == 4.0 and st["w_recv_min"] == 0.5
    assert st["w_pub"] == 8.5 and st["w_pub_min"] == 3.0
    assert st["w_cpu"] == 3.6 and st["w_cpu_min"] == 2.1
    assert st["w_perceive_sum"] == pytest.approx(6.5) and st["w_perceive_max"] == 3.5
    assert st["f_first_cue"] == pytest.approx(4.0)
    assert st["f_last_cue"] == pytest.approx(9.0) and st["f_ready"] == pytest.approx(10.0)


class _Pub:
    def __init__(self, log: list, key: str, calls: list | None = None) -> None:
        self.log, self.key, self.calls = log, key, calls

    def put(self, payload: bytes) -> None:
        self.log.append((self.key, payload))
        if self.calls is not None:
            self.calls.append((self.key, None))


class _Tracker:
    """Records the calls; fit_frame -> a pose-like result, identify_frame -> the same result,
    predict -> one prediction per camera."""

    def __init__(self, cams, calls: list) -> None:
        self.cams, self.calls = cams, calls
        self.lengths = BoneLengths()

    def fit_frame(self, frame, cues):
        self.calls.append(("fit_frame", frame))
        return SimpleNamespace(cues_3d=np.zeros((6, 3)), cue_valid=np.ones(6, bool), joints=np.zeros((20, 3)),
                               bvh_frame=np.zeros(10), timings_ms={"ik": 0.5})

    def identify_frame(self, result):
        self.calls.append(("identify_frame", None))
        return result

    def predict(self, frame):
        self.calls.append(("predict", frame))
        return {c: CuePrediction(c, frame, np.zeros((6, 2)), np.ones(6, bool), np.full(6, 5.0)) for c in self.cams}


@pytest.mark.parametrize("pose_first", [True, False])
def test_fuse_and_publish_order(pose_first):
    """Triggered rates: the pose leaves before the identity and predict run and before any
    prediction (the workers' deferred work they release cannot delay it); free-running:
    predictions first. The identity always runs before the prediction (a switch moves the
    tracks the prediction extrapolates)."""
    cams = ["a", "b"]
    log, calls = [], []
    keys = Keys("r")
    rt = SimpleNamespace(extra={}, meter=SimpleNamespace(add=lambda ms: calls.append(("meter", ms))))
    pose_pub = _Pub(log, "pose", calls)
    pf = PendingFrame(3, 1000 * MS, 0, cues={"a": _cues("a", 3, {"total": 1.0, "w_pub": 2.0})}, t_last_ns=1002 * MS)
    tracker = _Tracker(cams, calls)
    pose = fuse_and_publish(tracker, keys, pf, cams, {c: _Pub(log, f"pred/{c}") for c in cams},
                            pose_pub, rt, pose_first=pose_first)
    order = [k for k, _ in log]
    assert sorted(order) == ["pose", "pred/a", "pred/b"]
    assert (order[0] == "pose") == pose_first and (order[-1] == "pose") == (not pose_first)
    decoded = Pose.from_msgpack(dict(log)["pose"])
    assert decoded.frame == 3 and decoded.cameras_used == ("a",) and decoded.cameras_missing == ("b",)
    assert decoded.timings_ms["w_pub"] == 2.0 and decoded.timings_ms["lib_ik"] == 0.5
    assert pose.frame == 3
    assert Prediction.from_msgpack(dict(log)["pred/b"]).prediction.frame == 4
    steps = [c[0] for c in calls if c[0] != "meter"]
    assert steps == (["fit_frame", "pose", "identify_frame", "predict"] if pose_first else
                     ["fit_frame", "identify_frame", "predict", "pose"])


def test_idle_gc_collects_only_when_asked():
    class Cycle:
        def __init__(self):
            self.me = self

    was_enabled = gc.isenabled()
    g = IdleGC()
    g.start()
    try:
        assert not gc.isenabled() and gc.get_freeze_count() > 0
        for _ in range(5 * IdleGC.YOUNG_THRESHOLD):
            Cycle()                                   # garbage only a collection can free
        assert gc.get_count()[0] >= IdleGC.YOUNG_THRESHOLD   # nothing collected behind our back
        g.idle()
        assert g.collections == 1 and gc.get_count()[0] < IdleGC.YOUNG_THRESHOLD
        g.idle()                                      # below the threshold: nothing to do
        assert g.collections == 1
        g._last_full -= IdleGC.FULL_EVERY_S           # a full collection is due
        g.idle()
        assert g.collections == 2
    finally:
        g.stop()
    assert gc.isenabled() == was_enabled and gc.get_freeze_count() == 0


def _can_rt() -> bool:
    try:
        os.sched_setscheduler(0, os.sched_getscheduler(0), os.sched_getparam(0))
        return os.geteuid() == 0
    except (AttributeError, OSError):
        return False


@pytest.mark.skipif(not _can_rt(), reason="real-time scheduling needs root / CAP_SYS_NICE")
def test_enter_realtime_covers_every_thread_and_later_ones():
    """In a child process (pytest itself must not turn real-time)."""
    code = textwrap.dedent("""
        import os, threading, time
        from nodes.runtime import enter_realtime
        ev = threading.Event()
        th = threading.Thread(target=ev.wait, daemon=True); th.start()
        assert not enter_realtime(0)
        assert enter_realtime(7)
        late = []
        th2 = threading.Thread(target=lambda: late.append(os.sched_getscheduler(0))); th2.start(); th2.join()
        def policy(tid):
            try:
                return os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority
            except ProcessLookupError:      # th2: join() returns before its OS thread is gone
                return None
        pol = [p for t in os.listdir("/proc/self/task") if (p := policy(int(t))) is not None]
        print(len(pol), all(p == os.SCHED_FIFO for p, _ in pol), set(q for _, q in pol), late == [os.SCHED_FIFO])
        ev.set()
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert out.returncode == 0, out.stderr
    n, all_fifo, prios, late_fifo = out.stdout.split(" ", 3)
    assert int(n) >= 2 and all_fifo == "True" and prios == "{7}" and late_fifo.strip() == "True"


@pytest.mark.skipif(not (os.geteuid() == 0 and Path("/proc/self/autogroup").exists()),
                    reason="needs root and autogroup scheduling")
def test_child_priority_reaches_its_autogroup():
    """A node is its own session, i.e. its own autogroup: the niceness must be set there too."""
    from nodes.launcher import _child_setup

    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"], start_new_session=True,
                         preexec_fn=_child_setup(-3))
    try:
        text = Path(f"/proc/{p.pid}/autogroup").read_text()
        assert text.split()[-1] == "-3", text
        # the process's own niceness is raised by 3 from the launcher's (``os.nice``: relative;
        # the test may itself run under ``nice``)
        assert os.getpriority(os.PRIO_PROCESS, p.pid) == max(-20, os.getpriority(os.PRIO_PROCESS, 0) - 3)
    finally:
        p.kill()
        p.wait()


def test_launcher_gives_real_time_priority_to_the_trigger_path_only(tmp_path, tmp_path_factory, data_dir):
    from service_helpers import small_recording

    from nodes.launcher import DEFAULT_RT_PRIORITY, Launcher, RunConfig

    walk = small_recording(tmp_path_factory.getbasetemp(), data_dir)

    def prio(L, name):
        argv = L.nodes[name].argv
        return int(argv[argv.index("--rt-priority") + 1]) if "--rt-priority" in argv else 0

    common = dict(rig_path=walk / "rig.toml", source=f"replay:{walk}", record=tmp_path / "r",
                  rerun=f"save:{tmp_path / 'x.rrd'}", log_dir=tmp_path / "logs")
    L = Launcher(RunConfig(**common))                              # auto, triggered rate
    base = DEFAULT_RT_PRIORITY
    assert prio(L, "sync") == base + 2 and prio(L, "fusion") == base
    assert all(prio(L, n) == base for n in L.nodes if n.startswith("worker-"))
    assert prio(L, "recorder") == prio(L, "viewer") == 0
    assert all(prio(Launcher(RunConfig(**common, speed=None)), n) == 0 for n in L.nodes)   # free-run
    assert all(prio(Launcher(RunConfig(**common, rt_priority=0)), n) == 0 for n in L.nodes)
    assert prio(Launcher(RunConfig(**common, rt_priority=30)), "sync") == 32


@pytest.mark.skipif(not _can_rt(), reason="real-time scheduling needs root / CAP_SYS_NICE")
def test_thread_priority_switches_only_the_calling_thread():
    code = textwrap.dedent("""
        import os, threading
        from nodes.runtime import ThreadPriority, enter_realtime
        normal = ThreadPriority(); normal.normal(); normal.realtime_again()   # not real-time: no-op
        assert os.sched_getscheduler(0) == os.SCHED_OTHER and not normal.realtime
        ev = threading.Event()
        th = threading.Thread(target=ev.wait, daemon=True); th.start()
        assert enter_realtime(9)
        p = ThreadPriority()
        p.normal()
        other = [int(t) for t in os.listdir("/proc/self/task") if int(t) != threading.get_native_id()]
        print(os.sched_getscheduler(0) == os.SCHED_FIFO and os.sched_getparam(0).sched_priority == 1,
              all(os.sched_getparam(t).sched_priority == 9 for t in other))
        p.realtime_again()
        print(os.sched_getscheduler(0) == os.SCHED_FIFO, os.sched_getparam(0).sched_priority)
        ev.set()
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "True", "True", "9"]
