"""The node processes of a run: start them, restart those that die, stop them, sample their CPU.

Nodes are forked by the fork server (``nodes/forkserver.py``: one process that imported the
node modules and loaded the kernels once) once ``start_forkserver`` ran, else started as their
own processes. A node that dies is restarted (``RESTART_LIMIT`` times); a dead camera worker is
handed to the hot spare (``nodes/spare.py``) when there is one. Stopping sends SIGTERM, then
SIGKILL after ``STOP_TIMEOUT_S``, and kills whatever the node started itself (its process group).
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

from nodes.forkserver import ForkServer
from nodes.procs import _child_setup, kill_group, stop_all
from nodes.run_config import NodeProc

log = logging.getLogger(__name__)

STOP_TIMEOUT_S = 5.0
RESTART_LIMIT = 10
REALTIME_ROLES = ("sync", "camera", "fusion")   # the trigger -> pose path: ``nice`` and FIFO
BACKGROUND_NICE = 10           # viewer, recorder (when the frame path is not real-time), hot spare
BACKGROUND_ROLES = ("viewer", "recorder", "spare")
SINGLE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                     "NUMBA_NUM_THREADS": "1", "OPENCV_FOR_THREADS_NUM": "1"}


class Supervisor:
    """Starts, restarts and stops the ``NodeProc`` s of one run; logs in ``log_dir/<name>.log``.

    nice : the frame path's niceness (``--nice``); realtime : the frame path runs SCHED_FIFO;
    restart : restart nodes that die. ``spare`` (set by the launcher) takes over dead workers.
    """

    def __init__(self, nodes: dict[str, NodeProc], log_dir: Path, nice: int = 0, realtime: bool = False,
                 restart: bool = True) -> None:
        self.nodes = nodes
        self.log_dir = Path(log_dir)
        self.nice = nice
        self.realtime = realtime
        self.restart = restart
        self.stopping = False
        self.spare = None                  # nodes.spare.HotSpare
        self.forkserver: ForkServer | None = None

    # ------------------------------------------------------------ starting
    def env(self) -> dict:
        # one compute thread per node: the nodes already run in parallel, and library thread
        # pools in each of them (OpenCV, numba, BLAS) would only oversubscribe the cores
        return dict(os.environ, PYTHONUNBUFFERED="1", **SINGLE_THREAD_ENV)

    def nice_of(self, role: str) -> int:
        """The frame path gets ``--nice``; the hot spare runs below it. Viewer and recorder
        too when the frame path is not real-time; when it is, it preempts them anyway (they
        get what it leaves), and a niceness would only hand them to the host's other work."""
        if role in REALTIME_ROLES:
            return self.nice
        if role == "spare" or (role in BACKGROUND_ROLES and not self.realtime):
            return BACKGROUND_NICE
        return 0

    def start_forkserver(self) -> None:
        """Start the fork server (it preloads while the caller goes on; ``popen`` waits for it)."""
        self.forkserver = ForkServer(self.env(), self.log_path("forkserver"))
        self.forkserver.start()

    def close_forkserver(self) -> None:
        if self.forkserver is not None:
            self.forkserver.close()
            log.debug("fork server closed (preload took %s s)", self.forkserver.preload_s)
            self.forkserver = None

    def popen(self, argv: list[str], role: str, log_name: str, stdin=subprocess.DEVNULL):
        """``python argv...`` in its own session, its output appended to ``log_name``'s log:
        forked by the fork server when there is one (a ``ForkedProc``), else a ``Popen``."""
        if self.forkserver is not None:
            try:
                return self.forkserver.spawn(argv, self.log_path(log_name), self.nice_of(role),
                                             stdin_pipe=stdin == subprocess.PIPE)
            except RuntimeError as exc:       # the nodes start as their own processes instead
                log.warning("%s; starting the nodes as processes from now on", exc)
                self.close_forkserver()
        logf = open(self.log_path(log_name), "ab")
        try:
            return subprocess.Popen([sys.executable] + argv, stdout=logf, stderr=subprocess.STDOUT,
                                    stdin=stdin, env=self.env(), start_new_session=True,
                                    preexec_fn=_child_setup(self.nice_of(role)))
        finally:
            logf.close()

    def spawn(self, node: NodeProc) -> None:
        node.proc = self.popen(node.argv, node.role, node.name)
        node.cpu_last_s = 0.0
        log.debug("started %s pid %d", node.name, node.proc.pid)

    def log_path(self, name: str) -> Path:
        return self.log_dir / f"{name}.log"

    def log_tail(self, name: str, lines: int = 15) -> str:
        """The last lines of a node's log, indented, for an error message ('' if none)."""
        try:
            text = self.log_path(name).read_text(errors="replace").splitlines()[-lines:]
        except OSError:
            return ""
        return "".join(f"\n  | {line}" for line in text)

    # ------------------------------------------------------------ watching
    def sample_cpu(self) -> None:
        """The CPU seconds of every running node (``NodeProc.cpu_last_s``)."""
        import psutil

        for n in self.nodes.values():
            if n.proc is None or n.proc.poll() is not None:
                continue
            try:
                t = psutil.Process(n.proc.pid).cpu_times()
                n.cpu_last_s = t.user + t.system
            except (psutil.NoSuchProcess, psutil.AccessDenied):
                pass

    def supervise(self) -> list[str]:
        """Restart nodes that died; returns the names restarted now."""
        restarted = []
        for n in self.nodes.values():
            if n.proc is None or n.finished or self.stopping:
                continue
            rc = n.proc.poll()
            if rc is None:
                continue
            if rc == 0 and n.role == "sync":
                n.finished = True
                continue
            n.cpu_done_s += n.cpu_last_s
            n.cpu_last_s = 0.0
            kill_group(n.proc.pid)       # what the dead node started (the viewer's web server)
            if not self.restart or n.restarts >= RESTART_LIMIT:
                n.finished = True
                log.error("%s exited with %s; not restarted (see %s)%s", n.name, rc, self.log_path(n.name),
                          self.log_tail(n.name))
                continue
            n.restarts += 1
            log.warning("%s exited with %s; restarting (%d)", n.name, rc, n.restarts)
            if not (n.role == "camera" and self.spare is not None and self.spare.take_over(n)):
                self.spawn(n)
            restarted.append(n.name)
        return restarted

    # ------------------------------------------------------------ stopping
    def terminate(self, names: list[str]) -> None:
        """SIGTERM to these nodes, SIGKILL to those still running after ``STOP_TIMEOUT_S``."""
        stop_all([(n, self.nodes[n].proc) for n in names if self.nodes[n].proc is not None], STOP_TIMEOUT_S)
