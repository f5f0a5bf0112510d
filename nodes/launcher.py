"""The launcher behind ``mocap-rt run``: every node its own process on this host.

Start order: recorder and viewer (so they miss nothing), fusion, one camera worker per
camera; when all report ready, the sync node. Every node listens on its own loopback port
and connects to every node started before it and to the launcher (a full mesh of explicit
endpoints, each link opened from one side: no scouting, no router). A node that dies is
restarted (``RESTART_LIMIT`` times); a dead camera worker is replaced by the *hot spare*, a
worker process kept warm and idle (``camera_worker --standby``), so it is back within a
fraction of a second instead of a process start, and a new spare is started. Stopping (Ctrl-C,
``--duration``, end of a replay) stops the sync first, lets the last poses arrive, then
sends SIGTERM to the rest (SIGKILL after ``STOP_TIMEOUT_S``).
"""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from nodes.messages import Keys
from nodes.monitor import ServiceMonitor
from nodes.procs import _child_setup, _ephemeral_range, ensure_kernels_warm, free_port, kill_group, renice  # noqa: F401
from nodes.run_config import NodeProc, RunConfig, replay_frames, source_fps  # noqa: F401  (RunConfig: API)
from nodes.run_report import _json_safe, run_stats, status_line  # noqa: F401
from nodes.sources import parse_source
from nodes.transport import make_config, zenoh_argv

log = logging.getLogger(__name__)

STARTUP_TIMEOUT_S = 180.0      # the nodes only load the kernel cache (built before they start)
STOP_TIMEOUT_S = 5.0
DRAIN_S = 0.5                  # after the last trigger, wait this long for its pose
RESTART_LIMIT = 10
POLL_S = 0.05
STATUS_LINE_PERIOD_S = 1.0
DEFAULT_PREVIEW_EVERY = 6      # with a viewer: one JPEG per camera every 6 frames (5 per s at 30 fps)
REALTIME_ROLES = ("sync", "camera", "fusion")   # the trigger -> pose path: ``nice`` and FIFO
BACKGROUND_NICE = 10           # viewer, recorder (when the frame path is not real-time), hot spare
BACKGROUND_ROLES = ("viewer", "recorder", "spare")
DEFAULT_RT_PRIORITY = 10       # SCHED_FIFO priority of the workers (fusion 11, sync 12)
RT_PRIORITY_OFFSET = {"camera": 0, "fusion": 1, "sync": 2, "streamer": 2}   # streamer: ~0.3 ms a pose
SINGLE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                     "NUMBA_NUM_THREADS": "1", "OPENCV_FOR_THREADS_NUM": "1"}


class Launcher:
    """Starts, supervises and stops the node processes of one run; collects statistics."""

    def __init__(self, cfg: RunConfig) -> None:
        from mocap_rt.geometry.rig import read_rig
        from nodes.runtime import rig_name_for

        self.cfg = cfg
        kind, value = parse_source(cfg.source)
        self.source_kind = kind
        if not Path(cfg.rig_path).is_file():
            raise FileNotFoundError(f"--rig {cfg.rig_path}: no such file")
        self.rig = read_rig(cfg.rig_path)
        self.rig_name = cfg.rig_name or rig_name_for(cfg.rig_path, self.rig)
        self.keys = Keys(self.rig_name)
        self.base_fps = cfg.fps or source_fps(kind, value, self.rig)
        self.trigger_fps = 0.0 if cfg.speed is None else self.base_fps * cfg.speed
        self.realtime = False              # the frame path will run SCHED_FIFO (set by _rt_priority)
        self.rt_priority = self._rt_priority()
        self.n_replay_frames = replay_frames(kind, value)
        self.log_dir = Path(cfg.log_dir or tempfile.mkdtemp(prefix="mocap-rt-logs-"))
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.nodes: dict[str, NodeProc] = {}
        self.monitor_port = free_port()
        self.session = None
        self.monitor: ServiceMonitor | None = None
        self.stopping = False
        self.spare: subprocess.Popen | None = None     # the hot spare camera worker
        self.t_sync_start: float | None = None
        self._cpu_at_start: dict[str, float] = {}
        self.t_sync_stop: float | None = None
        self._plan()

    # ------------------------------------------------------------ planning
    def _rt_priority(self) -> int:
        """The workers' SCHED_FIFO priority (0 = normal scheduling).

        Auto (``cfg.rt_priority`` None): real-time at a triggered rate, where the trigger
        bounds the nodes' duty cycle; never when free-running (``--speed max``), where
        real-time nodes would take the whole machine. Needs root, CAP_SYS_NICE or an
        RLIMIT_RTPRIO of at least the priority; without it the nodes run normally."""
        import resource

        want = self.cfg.rt_priority
        if want is None:
            want = DEFAULT_RT_PRIORITY if self.trigger_fps > 0 else 0
        if want <= 0:
            return 0
        top = want + max(RT_PRIORITY_OFFSET.values())
        if os.geteuid() != 0 and resource.getrlimit(resource.RLIMIT_RTPRIO)[0] < top:
            log.info("real-time scheduling not permitted (needs root, CAP_SYS_NICE or RLIMIT_RTPRIO >= %d): "
                     "the nodes run at the normal priority", top)
            self.realtime = False
        else:
            self.realtime = True
        return want

    def _worker_sources(self) -> dict[str, str]:
        kind, value = parse_source(self.cfg.source)
        names = list(self.rig.names)
        if kind == "v4l2":
            devs = value.split(",")
            if len(devs) != len(names):
                raise ValueError(f"--source v4l2: {len(devs)} device(s) for {len(names)} rig cameras "
                                 f"(give one per camera, in rig order, comma-separated)")
            return {n: f"v4l2:{d}" for n, d in zip(names, devs)}
        if kind == "gst":          # one template for the rig: {camera} / {index} per camera
            return {n: "gst:" + value.replace("{camera}", n).replace("{index}", str(i)) for i, n in enumerate(names)}
        return {n: f"{kind}:{value}" for n in names}

    def _plan(self) -> None:
        cfg = self.cfg
        live = self.source_kind != "replay"
        common = ["--rig", str(cfg.rig_path), "--rig-name", self.rig_name]
        preview = cfg.preview_every if cfg.preview_every is not None else (DEFAULT_PREVIEW_EVERY if cfg.rerun else 0)
        plan: list[tuple[str, str, list[str]]] = []
        if cfg.record:
            plan.append(("recorder", "recorder", ["-m", "nodes.recorder", "--out", str(cfg.record),
                                                  "--fps", str(self.base_fps)] + (["--raw"] if live else [])))
        if cfg.rerun:
            plan.append(("viewer", "viewer", ["-m", "nodes.viewer", "--rerun", cfg.rerun,
                                              "--preview-every", str(preview)]))
        if cfg.stream:
            plan.append(("streamer", "streamer", ["-m", "nodes.streamer", "--stream", cfg.stream]
                         + (["--allow-remote-stream"] if cfg.allow_remote_stream else [])))
        plan.append(("fusion", "fusion", ["-m", "nodes.fusion_node", "--deadline-frac", str(cfg.deadline_frac),
                                          "--fps", str(self.base_fps)]
                     + (["--bones", str(cfg.bones)] if cfg.bones else [])))
        for cam, src in self._worker_sources().items():
            argv = ["-m", "nodes.camera_worker", "--camera", cam, "--source", src, "--fps", str(self.base_fps),
                    "--preview-every", str(preview)]
            if live and cfg.record:
                argv.append("--publish-frames")
            if cfg.backgrounds_from:
                argv += ["--backgrounds-from", str(cfg.backgrounds_from)]
            plan.append((f"worker-{cam}", "camera", argv))
        # sync connects to every other node and to the monitor: wait for all those links
        sync_argv = ["-m", "nodes.sync", "--fps", str(self.trigger_fps), "--expect-peers", str(len(plan) + 1)]
        if self.n_replay_frames and cfg.duration_s is None:
            sync_argv += ["--frames", str(self.n_replay_frames)]
        plan.append(("sync", "sync", sync_argv))
        ports = {name: free_port() for name, _, _ in plan}
        # each link is opened by one side only (the later node connects to the earlier ones
        # and to the launcher's monitor): two sessions racing to open the same link can
        # drop messages while one of them is torn down
        earlier: list[str] = []
        for name, role, argv in plan:
            others = [f"tcp/127.0.0.1:{ports[n]}" for n in earlier]
            others.append(f"tcp/127.0.0.1:{self.monitor_port}")
            earlier.append(name)
            z = zenoh_argv([f"tcp/127.0.0.1:{ports[name]}"], others)
            extra = list(cfg.extra_node_args.get(role, []))
            if self.rt_priority > 0 and role in RT_PRIORITY_OFFSET:
                extra = ["--rt-priority", str(self.rt_priority + RT_PRIORITY_OFFSET[role])] + extra
            self.nodes[name] = NodeProc(name, role, argv + common + ["--node", name] + z + extra, ports[name])

    # ------------------------------------------------------------ processes
    def _env(self) -> dict:
        # one compute thread per node: the nodes already run in parallel, and library thread
        # pools in each of them (OpenCV, numba, BLAS) would only oversubscribe the cores
        return dict(os.environ, PYTHONUNBUFFERED="1", **SINGLE_THREAD_ENV)

    def _nice(self, role: str) -> int:
        """The frame path gets ``--nice``; the hot spare runs below it. Viewer and recorder
        too when the frame path is not real-time; when it is, it preempts them anyway (they
        get what it leaves), and a niceness would only hand them to the host's other work."""
        if role in REALTIME_ROLES:
            return self.cfg.nice
        if role == "spare" or (role in BACKGROUND_ROLES and not self.realtime):
            return BACKGROUND_NICE
        return 0

    def _popen(self, argv: list[str], role: str, log_name: str, stdin=subprocess.DEVNULL) -> subprocess.Popen:
        logf = open(self.log_path(log_name), "ab")
        try:
            return subprocess.Popen([sys.executable] + argv, stdout=logf, stderr=subprocess.STDOUT,
                                    stdin=stdin, env=self._env(), start_new_session=True,
                                    preexec_fn=_child_setup(self._nice(role)))
        finally:
            logf.close()

    def _spawn(self, node: NodeProc) -> None:
        node.proc = self._popen(node.argv, node.role, node.name)
        node.cpu_last_s = 0.0
        log.debug("started %s pid %d", node.name, node.proc.pid)

    def _spawn_spare(self) -> None:
        """Start the hot spare: a camera worker that warms up on the first camera and waits,
        at a low priority (``BACKGROUND_NICE``) until it takes over."""
        first = next((n for n in self.nodes.values() if n.role == "camera"), None)
        if first is not None and self.cfg.restart:
            self.spare = self._popen(first.argv + ["--standby"], "spare", "spare", stdin=subprocess.PIPE)

    def _take_over(self, node: NodeProc) -> bool:
        """Hand ``node``'s flags to the hot spare; False if there is none (or it is gone)."""
        spare, self.spare = self.spare, None
        if spare is None:
            return False
        if spare.poll() is not None:
            log.warning("the hot spare had exited with %s%s", spare.returncode, self.log_tail("spare"))
            self._spawn_spare()
            return False
        job = {"argv": node.argv[2:], "log": str(self.log_path(node.name))}    # after "-m module"
        if not renice(spare.pid, self._nice(node.role)):
            log.warning("the hot spare's priority could not be raised to nice %d", self._nice(node.role))
        try:
            spare.stdin.write((json.dumps(job) + "\n").encode())
            spare.stdin.close()
        except OSError:
            spare.kill()
            return False
        node.proc = spare
        node.cpu_last_s = 0.0
        log.info("%s: taken over by the hot spare (pid %d)", node.name, spare.pid)
        self._spawn_spare()
        return True

    def _stop_spare(self) -> None:
        spare, self.spare = self.spare, None
        if spare is None:
            return
        try:
            spare.stdin.close()           # end of input: a waiting spare exits
        except OSError:
            pass
        spare.terminate()
        try:
            spare.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            spare.kill()
            spare.wait()
        kill_group(spare.pid)

    def log_path(self, name: str) -> Path:
        return self.log_dir / f"{name}.log"

    def log_tail(self, name: str, lines: int = 15) -> str:
        """The last lines of a node's log, indented, for an error message ('' if none)."""
        try:
            text = self.log_path(name).read_text(errors="replace").splitlines()[-lines:]
        except OSError:
            return ""
        return "".join(f"\n  | {line}" for line in text)

    def pid(self, name: str) -> int:
        return self.nodes[name].proc.pid

    def _sample_cpu(self) -> None:
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
            if not self.cfg.restart or n.restarts >= RESTART_LIMIT:
                n.finished = True
                log.error("%s exited with %s; not restarted (see %s)%s", n.name, rc, self.log_path(n.name),
                          self.log_tail(n.name))
                continue
            n.restarts += 1
            log.warning("%s exited with %s; restarting (%d)", n.name, rc, n.restarts)
            if not (n.role == "camera" and self._take_over(n)):
                self._spawn(n)
            restarted.append(n.name)
        return restarted

    # ------------------------------------------------------------ run phases
    def start(self) -> None:
        """Build the kernel cache if cold (one process), open the monitor session, start every
        node but sync, wait until they are ready (kernels loaded, a warm-up frame run), then
        the hot spare and the sync: the trigger never starts into a cold cluster."""
        import zenoh

        kind, value = parse_source(self.cfg.source)
        rec = Path(value) if kind in ("replay", "fake") else None
        if not ensure_kernels_warm(self.log_path("warmup"), self._env(), rec, lambda: self.stopping):
            return
        self.session = zenoh.open(make_config([f"tcp/127.0.0.1:{self.monitor_port}"], []))
        self.monitor = ServiceMonitor(self.session, self.keys)
        for n in self.nodes.values():
            if n.role != "sync":
                self._spawn(n)
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
                                       f"see {self.log_path(name)}{self.log_tail(name)}")
                if self.monitor.node_state(name) in ("ready", "running"):
                    waiting.remove(name)
            self.supervise()
            time.sleep(POLL_S)
        self._sample_cpu()
        self._cpu_at_start = {n.name: n.cpu_s for n in self.nodes.values()}   # start-up excluded
        self._spawn_spare()
        self._spawn(self.nodes["sync"])
        self.t_sync_start = time.monotonic()

    def supervise_for(self, seconds: float) -> None:
        """Keep supervising (restarts, CPU samples) for ``seconds`` (tests, scripts)."""
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end and not self.stopping:
            self.supervise()
            self._sample_cpu()
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
                                   f"{self.log_tail('sync')}")
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
                self.supervise()
                now = time.monotonic()
                if now - last_line >= STATUS_LINE_PERIOD_S:
                    self._sample_cpu()
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
            Path(self.cfg.stats).write_text(json.dumps(_json_safe(stats), indent=2))
        return stats

    def _terminate(self, names: list[str]) -> None:
        procs = [self.nodes[n] for n in names if self.nodes[n].proc is not None]
        for n in procs:
            if n.proc.poll() is None:
                n.proc.send_signal(signal.SIGTERM)
        t_end = time.monotonic() + STOP_TIMEOUT_S
        for n in procs:
            try:
                n.proc.wait(timeout=max(0.1, t_end - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning("%s did not stop in %.0f s: killing it", n.name, STOP_TIMEOUT_S)
                n.proc.kill()
                n.proc.wait()
            kill_group(n.proc.pid)       # anything the node left behind

    def stop(self) -> None:
        """Stop sync, let the last poses arrive, then stop the others (viewer/recorder last)."""
        self.stopping = True
        if self.monitor is not None:
            self._sample_cpu()
        if "sync" in self.nodes and self.nodes["sync"].proc is not None:
            self._terminate(["sync"])
            self.t_sync_stop = time.monotonic()
            t_end = time.monotonic() + DRAIN_S
            while self.monitor is not None and time.monotonic() < t_end and self.monitor.counts()[2] > 0:
                time.sleep(POLL_S)
        self._sample_cpu()
        order = [n for n, p in self.nodes.items() if p.role in ("camera", "fusion")]
        self._terminate(order)
        # the frame path is done: viewer and recorder may now use the whole machine to finish
        for n in self.nodes.values():
            if n.role in BACKGROUND_ROLES and self._nice(n.role) > self.cfg.nice and n.proc is not None \
                    and n.proc.poll() is None:
                renice(n.proc.pid, self.cfg.nice)
        self._terminate([n for n, p in self.nodes.items() if p.role in ("recorder", "viewer", "streamer")])
        self._stop_spare()
        if self.session is not None:
            self.monitor.close()
            self.session.close()
            self.session = None

    # ------------------------------------------------------------ statistics
    def status_line(self) -> str:
        """The live status line (``nodes.run_report.status_line``)."""
        return status_line(self)

    def stats(self) -> dict:
        """The run's statistics (``nodes.run_report.run_stats``; ``--stats`` writes them)."""
        return run_stats(self)
