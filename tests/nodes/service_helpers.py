"""Helpers for the service tests: a small studio recording, a probe session, waiting."""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

WALK_CLIP = "bvh/cmu/cmu_02_01_walk.bvh"


def ports_apart_from_the_launcher(n: int) -> list[int]:
    """``n`` free loopback TCP ports below the range a launcher draws its nodes' ports from
    (``nodes.procs.PORT_RANGE``). A ``mocap-rt run`` that a test starts draws its ports in its
    own process, so ``free_port()`` of the test's process could hand out one it later takes (a
    Zenoh node then listened on the port given to ``--rerun serve:WEB``)."""
    from nodes.procs import PORT_RANGE, free_port

    return [free_port((PORT_RANGE[0] - 10000, PORT_RANGE[0])) for _ in range(n)]


def small_recording(base: Path, data_dir: Path, name: str = "walk_320", seconds: float = 2.5,
                    n_cameras: int = 6) -> Path:
    """A 320x240 studio recording of a real CMU walk (made once per test session)."""
    from mocap_rt.studio.synth import make_rig, synthesize

    out = Path(base) / name
    if not (out / "recording.toml").exists():
        synthesize(data_dir / WALK_CLIP, out, rig=make_rig(n_cameras=n_cameras, size=(320, 240)),
                   seconds=seconds, truth_masks=False)
    return out


def probe_session(launcher):
    """A Zenoh session of the test itself, connected to every node of a launcher (loopback)."""
    import zenoh

    from nodes.transport import make_config

    eps = [f"tcp/127.0.0.1:{n.port}" for n in launcher.nodes.values()]
    eps.append(f"tcp/127.0.0.1:{launcher.monitor_port}")
    return zenoh.open(make_config(["tcp/127.0.0.1:0"], eps))


def wait_for(predicate, timeout_s: float, launcher=None, step_s: float = 0.05):
    """Poll ``predicate`` (supervising the launcher meanwhile) until truthy; returns its value."""
    t_end = time.monotonic() + timeout_s
    while True:
        v = predicate()
        if v or time.monotonic() > t_end:
            return v
        if launcher is not None:
            launcher.supervise_for(step_s)
        else:
            time.sleep(step_s)


class UdpSink:
    """Every datagram arriving on a loopback port, with its arrival time."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # room for the whole run's datagrams if this thread is not scheduled for a while
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.packets: list[tuple[float, bytes]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            self.packets.append((time.monotonic(), data))

    def drain(self, at_least: int, quiet_s: float = 0.5, timeout_s: float = 30.0) -> None:
        """Wait until ``at_least`` datagrams arrived and none for ``quiet_s``."""
        t_end = time.monotonic() + timeout_s
        n, t_n = -1, time.monotonic()
        while time.monotonic() < t_end:
            if len(self.packets) != n:
                n, t_n = len(self.packets), time.monotonic()
            elif n >= at_least and time.monotonic() - t_n >= quiet_s:
                return
            time.sleep(0.05)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.sock.close()


class HeadlessChromium:
    """Debian's chromium, headless, driven over the DevTools protocol on a pipe (no network).

    ``open(url)`` opens ``url`` in a new tab; ``capture(tab)`` returns PNG bytes of what it
    shows now (poll in real time: the web viewer streams and compiles WebAssembly, which
    virtual time does not cover).
    """

    FLAGS = ("--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
             "--no-first-run", "--no-default-browser-check", "--disable-extensions", "--mute-audio",
             "--remote-debugging-pipe")

    def __init__(self, exe: str, size=(1400, 900), user_dir: Path | None = None) -> None:
        import os
        import subprocess
        import tempfile

        self._to_r, self._to_w = os.pipe()       # we write commands -> chromium fd 3
        self._from_r, self._from_w = os.pipe()   # chromium fd 4 -> we read replies
        to_r, from_w = self._to_r, self._from_w

        def fds():  # DevTools pipe: chromium reads fd 3, writes fd 4
            a, b = os.dup(to_r), os.dup(from_w)     # out of the way of 3 and 4 first
            os.dup2(a, 3)
            os.dup2(b, 4)

        user_dir = user_dir or Path(tempfile.mkdtemp(prefix="chromium-"))
        self.proc = subprocess.Popen([exe, *self.FLAGS, f"--window-size={size[0]},{size[1]}",
                                      f"--user-data-dir={user_dir}", "about:blank"],
                                     pass_fds=(3, 4), preexec_fn=fds,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(to_r)
        os.close(from_w)
        self._buf = b""
        self._id = 0

    def _send(self, method: str, params: dict | None = None, session: str | None = None) -> dict:
        import json
        import os

        self._id += 1
        msg = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._to_w, json.dumps(msg).encode() + b"\0")
        while True:
            while b"\0" not in self._buf:
                chunk = os.read(self._from_r, 1 << 20)
                if not chunk:
                    raise RuntimeError("chromium closed the DevTools pipe")
                self._buf += chunk
            raw, self._buf = self._buf.split(b"\0", 1)
            reply = json.loads(raw)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})

    def open(self, url: str) -> str:
        """Open ``url`` in a new tab; returns the DevTools session of that tab."""
        target = self._send("Target.createTarget", {"url": url})["targetId"]
        return self._send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]

    def capture(self, session: str) -> bytes:
        """PNG bytes of what the tab shows now."""
        import base64

        shot = self._send("Page.captureScreenshot", {"format": "png"}, session)
        return base64.b64decode(shot["data"])

    def close(self) -> None:
        import os

        try:
            self._send("Browser.close")
        except Exception:
            pass
        try:
            self.proc.wait(timeout=10)
        except Exception:
            self.proc.kill()
        for fd in (self._to_w, self._from_r):
            try:
                os.close(fd)
            except OSError:
                pass
