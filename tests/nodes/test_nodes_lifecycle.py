"""The service's life cycle: every process it started (nodes, hot spare, the viewer's web
server) ends with it, also on Ctrl-C and after a node crash, leaving no listening port behind.
(The cold kernel cache built once before the nodes start: test_nodes_replay_run.)"""

import signal
import subprocess
import sys
from pathlib import Path

import psutil
import pytest
from service_helpers import ports_apart_from_the_launcher, small_recording, wait_for

pytestmark = pytest.mark.slow

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
    web, grpc = ports_apart_from_the_launcher(2)
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
        assert web_server, {p.pid: (_cmd(p)[:80], sorted(_listening_ports([p]))) for p in seen.values()}
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
