"""The fork server (``nodes/forkserver.py``): nodes forked warm, with their own argv, stdin, log,
session and priority; exit codes as ``Popen`` gives them; children end with the server."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
from service_helpers import wait_for

from nodes.forkserver import ForkServer
from nodes.supervisor import SINGLE_THREAD_ENV

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]


@pytest.fixture
def server(tmp_path, warm_kernels):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE), str(REPO)]), **SINGLE_THREAD_ENV)
    fs = ForkServer(env, tmp_path / "forkserver.log")
    fs.start()
    yield fs
    fs.close()


def _echo_line(log: Path) -> dict:
    return json.loads(next(line for line in log.read_text().splitlines() if line.startswith("{")))


def test_a_forked_node_gets_its_argv_stdin_log_session_priority_and_the_preloaded_kernels(server, tmp_path):
    log = tmp_path / "probe.log"
    p = server.spawn(["-m", "fork_probe", "echo", "3"], log, nice=5, stdin_pipe=True)
    p.stdin.write(b"hello node\n")
    p.stdin.close()
    assert p.wait(60) == 3 and p.poll() == 3 and p.returncode == 3
    out = _echo_line(log)
    assert out["argv"] == ["echo", "3"] and out["stdin"] == "hello node"
    assert out["sid"] == out["pid"] == p.pid                # its own session: kill_group ends its children
    assert out["nice"] == psutil.Process(server.proc.pid).nice() + 5
    assert out["held"] > 20, out                            # warm: the server's kernels, loaded once
    # the same probe as a process of its own holds none: the count is the fork server's doing
    plain = subprocess.run([sys.executable, "-m", "fork_probe", "echo", "0"], input="x\n", capture_output=True,
                           text=True, env=server.env, timeout=120)
    assert json.loads(plain.stdout)["held"] == 0, plain.stderr


def test_exit_codes_are_those_of_popen_and_a_crash_leaves_its_traceback(server, tmp_path):
    crash = server.spawn(["-m", "fork_probe", "crash"], tmp_path / "crash.log")
    assert crash.wait(60) == 1
    assert "RuntimeError: the probe crashed on purpose" in (tmp_path / "crash.log").read_text()
    sleeper = server.spawn(["-m", "fork_probe", "sleep"], tmp_path / "sleep.log")
    assert wait_for(lambda: "sleeping" in (tmp_path / "sleep.log").read_text(), 60)
    assert sleeper.poll() is None
    with pytest.raises(subprocess.TimeoutExpired):
        sleeper.wait(0.2)
    # ps shows the node's own command line, not the fork server's
    assert "-m fork_probe sleep" in " ".join(psutil.Process(sleeper.pid).cmdline())
    sleeper.kill()
    assert sleeper.wait(60) == -signal.SIGKILL
    with pytest.raises(ValueError):
        server.spawn([str(HERE / "fork_probe.py")], tmp_path / "x.log")      # modules only


@pytest.mark.parametrize("arg, code", [("4", 4), ("0", 0), ("bad input", 1)])
def test_a_quick_exit_node_runs_its_exit_handlers_but_not_the_teardown(server, tmp_path, arg, code):
    log = tmp_path / "quick.log"
    p = server.spawn(["-m", "fork_probe", "quick", arg], log)
    assert p.wait(60) == code
    text = log.read_text()
    assert "exit handler ran" in text                       # atexit: the logs' flush, multiprocessing
    assert "finaliser ran" not in text                      # the teardown of every object is skipped
    assert ("bad input" in text) == (code == 1)             # a message exit code is printed, as Python does


@pytest.mark.parametrize("how", ["close", "kill -9"])
def test_the_children_end_with_the_server(server, tmp_path, how):
    kids = [server.spawn(["-m", "fork_probe", "sleep"], tmp_path / f"s{i}.log") for i in range(2)]
    assert wait_for(lambda: all("sleeping" in (tmp_path / f"s{i}.log").read_text() for i in range(2)), 60)
    procs = [psutil.Process(k.pid) for k in kids]
    if how == "close":
        server.close()
    else:
        server.proc.kill()
    gone, alive = psutil.wait_procs(procs, timeout=30)
    assert not alive, [p.pid for p in alive]
    assert server.proc.wait(30) is not None
    assert all(k.wait(5) is not None for k in kids)


def test_the_supervisor_starts_processes_when_the_fork_server_is_gone(tmp_path, monkeypatch, warm_kernels):
    from nodes.run_config import NodeProc
    from nodes.supervisor import Supervisor

    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(HERE), str(REPO)]))
    node = NodeProc("probe", "camera", ["-m", "fork_probe", "echo", "4"], 0)
    sup = Supervisor({"probe": node}, tmp_path)
    sup.start_forkserver()
    sup.forkserver.proc.kill()              # it dies before it was ready
    sup.spawn(node)
    assert sup.forkserver is None and isinstance(node.proc, subprocess.Popen)
    assert node.proc.wait(120) == 4
    assert _echo_line(tmp_path / "probe.log")["held"] == 0     # a process of its own: nothing preloaded
