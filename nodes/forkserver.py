"""The fork server: one warm process that forks the node processes of a run.

Started as its own process, a node spends ~2.5 s of CPU before it can work: ~1 s importing
numpy, OpenCV, numba and Zenoh, ~1.5 s loading its cached numba kernels (LLVM links each
signature). A cluster start is nine such processes at once: ~25 s of CPU, ~12 s of wall on 2
cores, and again at every node restart. The fork server does it once: it imports the node
modules and loads every service kernel (``PRELOAD``, ``mocap_rt.warmup.load_cached_kernels``),
then forks one child per node; a child runs the node's ``main`` with its own argv, already warm.

Forking is safe here because the server has one thread (``Supervisor.env`` gives every library
one compute thread: no thread pool exists to be copied half-way) and opens no Zenoh session
(each child opens its own).

Protocol, over a ``SOCK_SEQPACKET`` socket pair (one message per packet, JSON):

* server -> launcher, once: ``{"ready": seconds}``;
* launcher -> server: ``{"id": n, "module": "nodes.x", "argv": [...], "nice": k}`` with two file
  descriptors attached (the child's stdin, and its log for stdout and stderr); the server
  answers ``{"id": n, "pid": pid}``;
* server -> launcher: ``{"exit": pid, "code": rc}`` when a child ends (``rc`` as ``Popen``: the
  exit status, or minus the signal that killed it).

A child is in its own session (``kill_group`` ends what it starts), gets SIGTERM when the server
dies, and the server gets SIGTERM when the launcher dies (``PR_SET_PDEATHSIG`` both), so every
node still ends with the launcher. End of the socket (the launcher closed it or died): the
server exits.

    python -m nodes.forkserver --fd N          (the launcher starts it: ``ForkServer``)
"""

from __future__ import annotations

import argparse
import atexit
import importlib
import json
import logging
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path

from setproctitle import setproctitle

from nodes.procs import _child_setup, die_with_parent

PRELOAD = ("nodes.camera_worker", "nodes.fusion_node", "nodes.sync", "nodes.recorder", "nodes.streamer")
MAX_MESSAGE = 1 << 16
READY_TIMEOUT_S = 120.0          # imports and kernel loads on a loaded 2-core machine (~3 s idle)
REAP_PERIOD_S = 0.05


# ---------------------------------------------------------------- the server process
def _child(req: dict, stdin_fd: int, log_fd: int, sock: socket.socket):
    """In the forked child: become the node (own session, priority, stdio), run its ``main``;
    returns its exit code as ``SystemExit`` takes it."""
    sock.close()
    os.setsid()
    _child_setup(int(req.get("nice", 0)))()      # what a Popen'd node gets: PDEATHSIG, niceness
    os.dup2(stdin_fd, 0)
    os.dup2(log_fd, 1)
    os.dup2(log_fd, 2)
    os.close(stdin_fd)
    os.close(log_fd)
    logging.root.handlers.clear()            # the node configures its own logging (run_node)
    sys.argv = [req["module"]] + list(req["argv"])
    # ps, top and psutil show the command the node would have had as its own process
    setproctitle(" ".join([sys.executable, "-m", req["module"]] + list(req["argv"])))
    try:
        return importlib.import_module(req["module"]).main()
    except SystemExit as exc:
        return exc.code
    except BaseException:       # noqa: BLE001 -- the node's own crash: its traceback to its log
        traceback.print_exc()
        return 1


def _quick_exit(code) -> None:
    """End a node whose module says ``QUICK_EXIT = True`` (it holds no file that only the
    interpreter's teardown would close: the frame-path nodes) with ``code`` (as ``SystemExit``
    takes it), after its exit handlers (the logs' flush, multiprocessing's children) but without
    that teardown of every module, object and loaded numba kernel the child has from the server:
    0.6-1.4 s a node, measured from its exit handlers to its end, at every cluster stop on 2
    cores. The recorder, viewer and streamer end as before."""
    if code is None:
        code = 0
    elif not isinstance(code, int):
        print(code, file=sys.stderr)
        code = 1
    atexit._run_exitfuncs()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _send(sock: socket.socket, msg: dict) -> None:
    sock.send(json.dumps(msg).encode())


def _fork(req: dict, fds: list[int], sock: socket.socket) -> int:
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        # the node's end is a process's end: the interpreter exits from here with its code and runs
        # the exit handlers (rerun finishes its file there), never returning into the server's loop
        code = _child(req, fds[0], fds[1], sock)
        if getattr(sys.modules.get(req["module"]), "QUICK_EXIT", False):
            _quick_exit(code)
        raise SystemExit(code)
    for fd in fds:
        os.close(fd)
    return pid


def preload() -> float:
    """Import the node modules and load every service kernel; returns the seconds it took."""
    from mocap_rt.warmup import load_cached_kernels

    t0 = time.perf_counter()
    for mod in PRELOAD:
        importlib.import_module(mod)
    load_cached_kernels()
    if threading.active_count() != 1 or len(os.listdir("/proc/self/task")) != 1:
        raise RuntimeError("the fork server has more than one thread after its preload: "
                           "forking it would copy a half-held lock (see Supervisor.env)")
    return time.perf_counter() - t0


def serve(sock: socket.socket) -> None:
    """Preload, say ready, then fork nodes and report their ends until the socket closes."""
    _send(sock, {"ready": round(preload(), 2)})
    while True:
        readable, _, _ = select.select([sock], [], [], REAP_PERIOD_S)
        if readable:
            msg, fds, _, _ = socket.recv_fds(sock, MAX_MESSAGE, 2)
            if not msg:
                return                          # the launcher closed the socket (or died)
            req = json.loads(msg)
            if len(fds) != 2:
                for fd in fds:
                    os.close(fd)
                _send(sock, {"id": req.get("id"), "error": "expected 2 file descriptors"})
                continue
            _send(sock, {"id": req["id"], "pid": _fork(req, fds, sock)})
        while True:
            try:
                pid, status = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                break
            if pid == 0:
                break
            _send(sock, {"exit": pid, "code": os.waitstatus_to_exitcode(status)})


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--fd", type=int, required=True, help="the launcher's end of the socket pair")
    args = p.parse_args(argv)
    sock = socket.socket(fileno=args.fd)
    try:
        serve(sock)
    except (BrokenPipeError, ConnectionResetError):
        pass                                    # the launcher is gone: so are we
    return 0


# ---------------------------------------------------------------- the launcher's side
def _exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    return True


class ForkedProc:
    """A node forked by the fork server, with the part of ``subprocess.Popen`` the supervisor
    uses (``pid``, ``stdin``, ``returncode``, ``poll``, ``wait``, ``send_signal``, ``terminate``,
    ``kill``). Its exit status comes from the server (it is the server's child)."""

    def __init__(self, server: ForkServer, pid: int, stdin) -> None:
        self.server, self.pid, self.stdin = server, pid, stdin
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            self.server.drain(0.0)
            code = self.server.exits.get(self.pid)
            if code is None and not self.server.alive() and not _exists(self.pid):
                code = -signal.SIGTERM     # it ended after the server (PR_SET_PDEATHSIG): its own code is lost
            self.returncode = code
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        t_end = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            left = None if t_end is None else t_end - time.monotonic()
            if left is not None and left <= 0:
                raise subprocess.TimeoutExpired(f"pid {self.pid}", timeout)
            step = REAP_PERIOD_S if left is None else min(REAP_PERIOD_S, left)
            if self.server.alive():
                self.server.drain(step)
            else:
                time.sleep(step)
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            try:
                os.kill(self.pid, sig)
            except ProcessLookupError:
                pass

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


class ForkServer:
    """The launcher's handle on one fork server process (``start`` it, ``spawn`` nodes, ``close``)."""

    def __init__(self, env: dict, log_path: Path) -> None:
        self.env, self.log_path = env, Path(log_path)
        self.proc: subprocess.Popen | None = None
        self.sock: socket.socket | None = None
        self.exits: dict[int, int] = {}
        self.preload_s: float | None = None
        self._replies: dict[int, dict] = {}
        self._next_id = 0

    def start(self) -> None:
        """Start the server; it preloads while the caller goes on (``wait_ready``)."""
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        with open(self.log_path, "ab") as logf:
            self.proc = subprocess.Popen([sys.executable, "-m", "nodes.forkserver", "--fd", str(theirs.fileno())],
                                         pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL, stdout=logf,
                                         stderr=subprocess.STDOUT, env=self.env, start_new_session=True,
                                         preexec_fn=die_with_parent)
        theirs.close()
        self.sock = ours

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None and self.sock is not None

    def wait_ready(self, timeout_s: float = READY_TIMEOUT_S) -> float:
        """Block until the server has preloaded; returns its preload seconds. Raises if it died."""
        t_end = time.monotonic() + timeout_s
        while self.preload_s is None:
            if not self.alive():
                raise RuntimeError(f"the fork server exited with {self.proc.returncode} before it was "
                                   f"ready (log {self.log_path})")
            if time.monotonic() > t_end:
                raise RuntimeError(f"the fork server not ready after {timeout_s:.0f} s (log {self.log_path})")
            self.drain(REAP_PERIOD_S)
        return self.preload_s

    def drain(self, timeout_s: float) -> None:
        """Read what the server sent (ready, spawn replies, exits), waiting at most ``timeout_s``."""
        if self.sock is None:
            return
        wait = timeout_s
        while select.select([self.sock], [], [], wait)[0]:
            wait = 0.0
            try:
                msg = self.sock.recv(MAX_MESSAGE)
            except OSError:
                msg = b""
            if not msg:                           # the server is gone
                self.sock.close()
                self.sock = None
                return
            m = json.loads(msg)
            if "exit" in m:
                self.exits[int(m["exit"])] = int(m["code"])
            elif "ready" in m:
                self.preload_s = float(m["ready"])
            else:
                self._replies[m["id"]] = m

    def spawn(self, argv: list[str], log_path: Path, nice: int = 0, stdin_pipe: bool = False) -> ForkedProc:
        """Fork ``python argv...`` (``argv`` = ``["-m", module, flags...]``), output appended to
        ``log_path``; ``stdin_pipe``: the returned process's ``stdin`` is a pipe to it."""
        if argv[:1] != ["-m"]:
            raise ValueError(f"the fork server runs node modules (-m MODULE ...), not {argv[:2]}")
        self.wait_ready()
        r, w = os.pipe() if stdin_pipe else (os.open(os.devnull, os.O_RDONLY), None)
        logfd = os.open(log_path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        self._next_id += 1
        req = {"id": self._next_id, "module": argv[1], "argv": argv[2:], "nice": nice}
        try:
            socket.send_fds(self.sock, [json.dumps(req).encode()], [r, logfd])
        except OSError as exc:
            if w is not None:
                os.close(w)
            raise RuntimeError(f"the fork server is gone ({exc}; log {self.log_path})") from exc
        finally:
            os.close(r)
            os.close(logfd)
        t_end = time.monotonic() + READY_TIMEOUT_S
        while self._next_id not in self._replies:
            if not self.alive() or time.monotonic() > t_end:
                if w is not None:
                    os.close(w)
                raise RuntimeError(f"the fork server did not start {argv[1]} (log {self.log_path})")
            self.drain(REAP_PERIOD_S)
        reply = self._replies.pop(self._next_id)
        if "pid" not in reply:
            raise RuntimeError(f"the fork server refused {argv[1]}: {reply.get('error')}")
        return ForkedProc(self, int(reply["pid"]), os.fdopen(w, "wb", buffering=0) if w is not None else None)

    def close(self) -> None:
        """End the server (its remaining children get SIGTERM as it exits)."""
        if self.sock is not None:
            self.sock.close()
            self.sock = None
        if self.proc is not None and self.proc.poll() is None:
            try:
                self.proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


if __name__ == "__main__":
    sys.exit(main())
