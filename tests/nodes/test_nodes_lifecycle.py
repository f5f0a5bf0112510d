"""The service's life cycle: a cold kernel cache is built once before the nodes start, and
every process it started (nodes, hot spare, the viewer's web server) ends with it, also on
Ctrl-C and after a node crash, leaving no listening port behind."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import psutil
import pytest
from service_helpers import small_recording, wait_for

from nodes.launcher import free_port

pytestmark = pytest.mark.slow

MIN_POSE_FRACTION = 0.75          # of the triggered frames, from a cold cache: nodes that compile
                                  # at start left 5 %; 98-100 % on an idle machine is the demo's
                                  # figure (bench), a busy CI box loses a few frames
WAIT_S = 60.0                     # a process to end or start on a loaded machine (seconds when idle)


@pytest.fixture(scope="module")
def walk(tmp_path_factory, data_dir):
    return small_recording(tmp_path_factory.getbasetemp(), data_dir)


def _tree(pid: int) -> list[psutil.Process]:
    try:
        return psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []


def _listening_ports(procs) -> set[int]:
    out = set()
    for p in procs:
        try:
            out |= {c.laddr.port for c in p.net_connections(kind="inet") if c.status == psutil.CONN_LISTEN}
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            pass
    return out


def _alive(procs) -> list[psutil.Process]:
    out = []
    for p in procs:
        try:
            if p.is_running() and p.status() != psutil.STATUS_ZOMBIE:
                out.append(p)
        except psutil.NoSuchProcess:
            pass
    return out


def _cmd(p: psutil.Process) -> str:
    try:
        return " ".join(p.cmdline())
    except psutil.NoSuchProcess:
        return ""


def test_every_child_ends_on_ctrl_c_and_after_a_crash(walk, tmp_path):
    web, grpc = free_port(), free_port()
    exe = str(Path(sys.executable).with_name("mocap-rt"))
    logf = open(tmp_path / "run.log", "wb")
    run = subprocess.Popen([exe, "run", "--source", f"replay:{walk}", "--duration", "600", "--quiet",
                            "--rerun", f"serve:{web}:{grpc}", "--record", str(tmp_path / "rec"),
                            "--log-dir", str(tmp_path / "logs")], stdout=logf, stderr=subprocess.STDOUT)
    seen: dict[int, psutil.Process] = {}
    try:
        def up():
            procs = _tree(run.pid)
            seen.update({p.pid: p for p in procs})
            cmds = [_cmd(p) for p in procs]
            return (web in _listening_ports(procs) and any("--standby" in c for c in cmds)
                    and any("nodes.sync" in c for c in cmds))
        assert wait_for(up, 120), (tmp_path / "run.log").read_text()
        ports = _listening_ports(seen.values())
        assert {web, grpc} <= ports
        # a node crash: kill -9 the viewer; its web server must not outlive it
        viewer = next(p for p in seen.values() if "nodes.viewer" in _cmd(p))
        web_server = [p for p in viewer.children(recursive=True) if "--serve-web" in _cmd(p)]
        assert web_server
        viewer.kill()
        assert wait_for(lambda: not _alive(web_server), WAIT_S), "the crashed viewer's web server survived it"
        # the launcher restarts the viewer, with a new web server (listening: its ports must be
        # closed at the end too)
        def restarted():
            procs = _tree(run.pid)
            seen.update({p.pid: p for p in procs})
            new = [p for p in procs if "--serve-web" in _cmd(p) and p not in web_server]
            return new if _listening_ports(new) else None
        assert wait_for(restarted, WAIT_S), [_cmd(p) for p in _tree(run.pid)]
        ports |= _listening_ports(_tree(run.pid))
        # Ctrl-C
        run.send_signal(signal.SIGINT)
        assert run.wait(timeout=60) == 0, (tmp_path / "run.log").read_text()[-3000:]
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
        logf.close()
    assert len(seen) >= 13          # 6 workers, spare, fusion, sync, recorder, viewer x2, web server
    left = wait_for(lambda: not _alive(seen.values()), WAIT_S) or _alive(seen.values())
    assert left is True, [f"{p.pid} {_cmd(p)}" for p in left]
    still = {c.laddr.port for c in psutil.net_connections(kind="inet")
             if c.status == psutil.CONN_LISTEN and c.laddr.port in ports}
    assert not still, f"ports still listening after the service ended: {sorted(still)}"


@pytest.mark.cold_cache
def test_demo_path_from_an_empty_kernel_cache(replay_run):
    """An empty numba cache (conftest.replay_run: the demo path, viewer and recorder on, with
    ``NUMBA_CACHE_DIR`` an empty directory): the launcher builds it in one process before any
    node starts; the nodes only load it (no cache file changes after the warm-up), and the
    replay's frames nearly all give a pose."""
    assert replay_run.returncode == 0, replay_run.stderr[-3000:]
    cache, stats = replay_run.numba_cache, replay_run.stats
    stamp = json.loads((cache / "mocap_rt-numba-kernels.json").read_text())
    assert stamp["compiled"] > 10, stamp               # the warm-up compiled them ...
    t_stamp = os.stat(cache / "mocap_rt-numba-kernels.json").st_mtime
    index = list(cache.rglob("*.nbi"))
    assert len(index) >= stamp["compiled"] // 2
    later = [p.name for p in index if p.stat().st_mtime > t_stamp]
    assert not later, f"nodes compiled kernels after the warm-up: {later}"     # ... nobody else
    warm_log = (replay_run.logs / "warmup.log").read_text()
    assert "kernel signatures compiled" in warm_log
    print(f"cold start: {stamp['compiled']} kernels compiled in {stamp['seconds']} s; "
          f"{stats['poses_published']}/{stats['frames_triggered']} poses, latency {stats['latency_ms']}")
    assert stats["frames_triggered"] > 0
    # the launcher's monitor and the recorder count the same poses (their frame windows keep a
    # pose that a busy host delays: nodes/frame_window.RECORD_BEHIND / RECORD_AHEAD)
    with np.load(replay_run.rec / "poses.npz") as z:
        assert len(z["frames"]) == stats["poses_published"], stats
    assert stats["poses_published"] >= MIN_POSE_FRACTION * stats["frames_triggered"], stats
