"""The launcher behind ``mocap-rt run``: every node its own process on this host.

``Launcher`` runs the phases of one run over the parts that own them: the plan
(``nodes/plan.py``: processes, flags, ports, priorities), the processes
(``nodes/supervisor.py``, with the hot spare of ``nodes/spare.py``), the service as the
launcher's own Zenoh session sees it (``nodes/monitor.py``) and the report
(``nodes/run_report.py``: status line, statistics).

Start order: the fork server (``nodes/forkserver.py``: imports the nodes and loads the kernels
once, then forks every node warm), recorder and viewer (so they miss nothing), fusion, one
camera worker per camera; when all report ready, the hot spare and the sync node. Stopping
(Ctrl-C, ``--duration``, end of a replay) stops the sync first, lets the last poses arrive,
then stops the others.
"""

from __future__ import annotations

import json
import logging
import signal
import sys
import tempfile
import time
from pathlib import Path

from mocap_rt.io.files import atomic_write_text
from nodes.messages import Keys
from nodes.monitor import ServiceMonitor
from nodes.plan import DEFAULT_RT_PRIORITY, plan_run  # noqa: F401  (DEFAULT_RT_PRIORITY: API)
from nodes.procs import _child_setup, _ephemeral_range, ensure_kernels_warm, free_port, renice  # noqa: F401
from nodes.run_config import NodeProc, RunConfig  # noqa: F401  (RunConfig: API)
from nodes.run_report import _json_safe, run_stats, status_line  # noqa: F401
from nodes.sources import parse_source
from nodes.spare import HotSpare
from nodes.supervisor import BACKGROUND_ROLES, Supervisor
from nodes.transport import make_config

log = logging.getLogger(__name__)

STARTUP_TIMEOUT_S = 180.0      # the nodes only load the kernel cache (built before they start)
DRAIN_S = 0.5                  # after the last trigger, wait this long for its pose
POLL_S = 0.05
STATUS_LINE_PERIOD_S = 1.0


class Launcher:
    """Starts, supervises and stops the node processes of one run; collects statistics."""

    def __init__(self, cfg: RunConfig) -> None:
        self.cfg = cfg
        plan = plan_run(cfg)
        self.rig, self.rig_name, self.keys = plan.rig, plan.rig_name, Keys(plan.rig_name)
        self.trigger_fps, self.rt_priority = plan.trigger_fps, plan.rt_priority
        self.nodes: dict[str, NodeProc] = plan.nodes
        self.monitor_port = plan.monitor_port
        self.log_dir = Path(cfg.log_dir or tempfile.mkdtemp(prefix="mocap-rt-logs-"))
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.procs = Supervisor(self.nodes, self.log_dir, cfg.nice, plan.realtime, cfg.restart)
        self.procs.spare = self.hot_spare = HotSpare(self.procs)
        self.session = None
        self.monitor: ServiceMonitor | None = None
        self.t_sync_start: float | None = None
        self.t_sync_stop: float | None = None
        self.cpu_at_start: dict[str, float] = {}

    @property
    def spare(self):
        """The hot spare's process (None when there is none)."""
        return self.hot_spare.proc

    @property
    def stopping(self) -> bool:
        return self.procs.stopping

    @stopping.setter
    def stopping(self, value: bool) -> None:
        self.procs.stopping = value

    def pid(self, name: str) -> int:
        return self.nodes[name].proc.pid

    def log_path(self, name: str) -> Path:
        return self.procs.log_path(name)

    # ------------------------------------------------------------ run phases
    def start(self) -> None:
        """Build the kernel cache if cold (one process), open the monitor session, start every
        node but sync, wait until they are ready (kernels loaded, a warm-up frame run), then
        the hot spare and the sync: the trigger never starts into a cold cluster."""
        import zenoh

        kind, value = parse_source(self.cfg.source)
        rec = Path(value) if kind in ("replay", "fake") else None
        if not ensure_kernels_warm(self.log_path("warmup"), self.procs.env(), rec, lambda: self.stopping):
            return
        self.procs.start_forkserver()          # preloads while the monitor session opens
        self.session = zenoh.open(make_config([f"tcp/127.0.0.1:{self.monitor_port}"], []))
        self.monitor = ServiceMonitor(self.session, self.keys)
        for n in self.nodes.values():
            if n.role != "sync":
                self.procs.spawn(n)
        waiting = [n.name for n in self.nodes.values() if n.role != "sync"]
        t_end = time.monotonic() + STARTUP_TIMEOUT_S
        while waiting:
            if self.stopping:
                return
            if time.monotonic() > t_end:
                raise RuntimeError(f"nodes not ready after {STARTUP_TIMEOUT_S:.0f} s: {waiting} "
                                   f"(logs in {self.log_dir})")
            for name in list(waiting):
                n = self.nodes[name]
                if n.proc.poll() is not None and (not self.cfg.restart or n.restarts >= 2):
                    raise RuntimeError(f"{name} failed at start (exit {n.proc.returncode}); "
                                       f"see {self.log_path(name)}{self.procs.log_tail(name)}")
                if self.monitor.node_state(name) in ("ready", "running"):
                    waiting.remove(name)
            self.procs.supervise()
            time.sleep(POLL_S)
        self.procs.sample_cpu()
        self.cpu_at_start = {n.name: n.cpu_s for n in self.nodes.values()}   # start-up excluded
        self.hot_spare.start()
        self.procs.spawn(self.nodes["sync"])
        self.t_sync_start = time.monotonic()

    def supervise_for(self, seconds: float) -> None:
        """Keep supervising (restarts, CPU samples) for ``seconds`` (tests, scripts)."""
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end and not self.stopping:
            self.procs.supervise()
            self.procs.sample_cpu()
            time.sleep(POLL_S)

    def done(self) -> bool:
        """True once the run should end (``duration_s`` after the first trigger, or the replay
        was played once)."""
        if self.t_sync_start is None:
            return self.stopping
        if self.nodes["sync"].finished or self.stopping:
            return True
        if self.cfg.duration_s is None:
            return False
        t0_ns = self.monitor.first_trigger_ns()       # the duration counts from the first trigger
        if t0_ns is None:
            if time.monotonic() - self.t_sync_start > STARTUP_TIMEOUT_S:
                raise RuntimeError(f"the sync node sent no trigger in {STARTUP_TIMEOUT_S:.0f} s"
                                   f"{self.procs.log_tail('sync')}")
            return False
        return time.monotonic_ns() - t0_ns >= self.cfg.duration_s * 1e9

    def run(self) -> dict:
        """start -> supervise until done -> stop; returns the statistics dict."""
        prev = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}

        def _stop(signum, frame):  # noqa: ARG001
            self.stopping = True
        for s in prev:
            signal.signal(s, _stop)
        try:
            self.start()
            last_line = 0.0
            tty = sys.stderr.isatty()
            while not self.done():
                self.procs.supervise()
                now = time.monotonic()
                if now - last_line >= STATUS_LINE_PERIOD_S:
                    self.procs.sample_cpu()
                    last_line = now
                    if self.cfg.status_line:
                        line = self.status_line()
                        print(("\r" + line) if tty else line, end="" if tty else "\n", file=sys.stderr, flush=True)
                time.sleep(POLL_S)
            if self.cfg.status_line and sys.stderr.isatty():
                print(file=sys.stderr)
        finally:
            self.stop()
            for s, h in prev.items():
                signal.signal(s, h)
        stats = self.stats()
        if self.cfg.stats:
            Path(self.cfg.stats).parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(self.cfg.stats, json.dumps(_json_safe(stats), indent=2))
        return stats

    def stop(self) -> None:
        """Stop sync, let the last poses arrive, then stop the others (viewer/recorder last)."""
        self.stopping = True
        if self.monitor is not None:
            self.procs.sample_cpu()
        if "sync" in self.nodes and self.nodes["sync"].proc is not None:
            self.procs.terminate(["sync"])
            self.t_sync_stop = time.monotonic()
            t_end = time.monotonic() + DRAIN_S
            while self.monitor is not None and time.monotonic() < t_end and self.monitor.counts()[2] > 0:
                time.sleep(POLL_S)
        self.procs.sample_cpu()
        self.procs.terminate([n for n, p in self.nodes.items() if p.role in ("camera", "fusion")])
        # the frame path is done: viewer and recorder may now use the whole machine to finish
        for n in self.nodes.values():
            if n.role in BACKGROUND_ROLES and self.procs.nice_of(n.role) > self.cfg.nice and n.proc is not None \
                    and n.proc.poll() is None:
                renice(n.proc.pid, self.cfg.nice)
        self.procs.terminate([n for n, p in self.nodes.items() if p.role in ("recorder", "viewer", "streamer")])
        self.hot_spare.stop()
        self.procs.close_forkserver()
        if self.session is not None:
            self.monitor.close()
            self.session.close()
            self.session = None

    # ------------------------------------------------------------ report
    def status_line(self) -> str:
        """The live status line (``nodes.run_report.status_line``)."""
        return status_line(self)

    def stats(self) -> dict:
        """The run's statistics (``nodes.run_report.run_stats``; ``--stats`` writes them)."""
        return run_stats(self)
