"""Child processes of the service: loopback ports, priorities, clean ends, the kernel cache.

Every process the service starts dies with its parent (``PR_SET_PDEATHSIG``), runs in its
own session (so ``kill_group`` also ends whatever it started itself, e.g. the viewer's
``rerun --serve-web``) and gets its niceness in its scheduling *autogroup* too.
"""

from __future__ import annotations

import ctypes
import logging
import os
import random
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

log = logging.getLogger(__name__)

PORT_RANGE = (20000, 32000)    # listen ports are drawn here, below the kernel's ephemeral range
WARMUP_TIMEOUT_S = 1800.0      # one process compiling every kernel on a loaded 2-core machine


def _ephemeral_range() -> tuple[int, int]:
    try:
        lo, hi = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()
        return int(lo), int(hi)
    except (OSError, ValueError):
        return 32768, 60999


_rng = random.Random()
_handed_out: set[int] = set()   # never the same port twice: the nodes of one service bind later


def free_port(port_range: tuple[int, int] = PORT_RANGE) -> int:
    """A loopback TCP port in ``port_range`` that is free now, outside the ephemeral range (so
    that no outgoing connection of another process can take it before our node binds it) and
    not handed out before by this process (the ports of one service are all drawn before any
    node binds)."""
    lo_e, hi_e = _ephemeral_range()
    for _ in range(1000):
        port = _rng.randrange(*port_range)
        if lo_e <= port <= hi_e or port in _handed_out:
            continue
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            _handed_out.add(port)
            return port
    raise RuntimeError("no free TCP port found for the service")


def die_with_parent() -> None:
    """preexec_fn: SIGTERM when the parent dies (Linux ``prctl(PR_SET_PDEATHSIG)``)."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)
    except OSError:
        pass


def set_autogroup_nice(nice: int, pid: int | str = "self") -> bool:
    """The niceness of ``pid``'s scheduling autogroup (its session); False if not permitted."""
    try:
        with open(f"/proc/{pid}/autogroup", "w") as f:
            f.write(str(nice))
        return True
    except OSError:
        return False      # no autogroups, or not permitted


def _child_setup(nice: int):
    """preexec_fn: the child gets SIGTERM if the launcher dies (Linux prctl PR_SET_PDEATHSIG)
    and, if asked, a scheduling priority (negative ``nice`` needs root or CAP_SYS_NICE).

    Every node is started in its own session (``start_new_session``), and with the kernel's
    autogroup scheduling (``/proc/sys/kernel/sched_autogroup_enabled``, on in most distros) a
    new session is a new scheduling group: CPU is shared between the *groups* first, and a
    process's own niceness only counts inside its group. So the niceness is also given to the
    node's autogroup (``/proc/self/autogroup``), else it would have no effect against other
    work on the host."""
    def setup() -> None:
        die_with_parent()
        if nice:
            try:
                os.nice(nice)
            except OSError:
                pass      # not permitted: run at the normal priority
            set_autogroup_nice(nice)
    return setup


def renice(pid: int, nice: int) -> bool:
    """Set every thread of ``pid`` and its autogroup to ``nice`` (raising a priority needs
    root or CAP_SYS_NICE); False if not permitted."""
    ok = True
    try:
        tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except OSError:
        tids = [pid]
    for tid in tids:
        try:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
        except OSError:
            ok = False
    return set_autogroup_nice(nice, pid) and ok


def kill_group(pid: int) -> None:
    """SIGKILL whatever is left of the process group ``pid`` led (a node's own children)."""
    try:
        os.killpg(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def stop_all(procs: list[tuple[str, subprocess.Popen]], timeout_s: float) -> None:
    """SIGTERM to every (name, process), SIGKILL to those still running after ``timeout_s``
    (one deadline for all), then whatever each left in its process group."""
    for _, p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    t_end = time.monotonic() + timeout_s
    for name, p in procs:
        try:
            p.wait(timeout=max(0.1, t_end - time.monotonic()))
        except subprocess.TimeoutExpired:
            log.warning("%s did not stop in %.0f s: killing it", name, timeout_s)
            p.kill()
            p.wait()
        kill_group(p.pid)


def ensure_kernels_warm(log_path: Path, env: dict, rec: Path | None = None, should_stop=lambda: False) -> bool:
    """Build the numba kernel cache in ONE process (``python -m mocap_rt.warmup``) unless its
    stamp says it is warm; the nodes then only load it. Returns False if ``should_stop()``
    became true meanwhile (the warm-up is stopped). Raises if the warm-up failed."""
    from mocap_rt.warmup import is_warm

    if is_warm():
        return True
    print("mocap-rt: the numba kernel cache is cold (first run, or the kernels changed): "
          "compiling it once, in one process, before the nodes start ...", file=sys.stderr, flush=True)
    argv = [sys.executable, "-m", "mocap_rt.warmup"] + (["--rec", str(rec)] if rec is not None else [])
    t0 = time.monotonic()
    with open(log_path, "ab") as logf:
        proc = subprocess.Popen(argv, stdout=logf, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                env=env, start_new_session=True, preexec_fn=die_with_parent)
    try:
        while proc.poll() is None:
            if should_stop() or time.monotonic() - t0 > WARMUP_TIMEOUT_S:
                proc.terminate()
                proc.wait(timeout=10)
                if should_stop():
                    return False
                raise RuntimeError(f"kernel warm-up not done after {WARMUP_TIMEOUT_S:.0f} s (log {log_path})")
            time.sleep(0.1)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    if proc.returncode != 0:
        tail = "".join(f"\n  | {line}" for line in log_path.read_text(errors="replace").splitlines()[-15:])
        raise RuntimeError(f"kernel warm-up failed (exit {proc.returncode}), log {log_path}{tail}")
    log.info("kernel cache built in %.1f s (log %s)", time.monotonic() - t0, log_path)
    print(f"mocap-rt: kernel cache built in {time.monotonic() - t0:.0f} s", file=sys.stderr, flush=True)
    return True
