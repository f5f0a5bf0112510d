"""``--rerun serve``: the web viewer on 127.0.0.1 shows the running service in headless Chromium."""

import shutil
import time

import cv2
import numpy as np
import psutil
import pytest
from service_helpers import HeadlessChromium, small_recording, wait_for

from nodes.launcher import Launcher, RunConfig, free_port
from nodes.viewer import web_viewer_url

pytestmark = pytest.mark.slow

VIEWER_WAIT_S = 150.0     # at most: wasm download + compile + first data, software rendering, loaded host
SHOT_EVERY_S = 3.0
PREVIEW_EVERY = 6         # fewer images: the software-rendered browser keeps up better
WAIT_S = 90.0             # the first poses / the viewer's listening sockets (seconds when idle)


@pytest.fixture(scope="module")
def chromium() -> str:
    """Debian's chromium, installed by `make system-deps` (which `make test` runs)."""
    exe = shutil.which("chromium")
    assert exe, "chromium is missing: run `make system-deps` (Debian package chromium)"
    return exe


def _listening(pids) -> list[tuple[str, int]]:
    out = []
    for pid in pids:
        try:
            for c in psutil.Process(pid).net_connections(kind="inet"):
                if c.status == psutil.CONN_LISTEN:
                    out.append((c.laddr.ip, c.laddr.port))
        except psutil.NoSuchProcess:
            pass
    return out


def _shows_the_service(png: bytes) -> dict[str, bool]:
    """What a screenshot of the web viewer shows: cue overlays (yellow head cue), camera images."""
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None and img.shape[1] == 1400
    # the head cue's ellipse/point (yellow, BGR ~ (0, 220, 255)) is drawn over the cameras
    yellow = ((img[..., 2] > 200) & (img[..., 1] > 170) & (img[..., 0] < 90)).sum()
    # at least one camera image (mid-tone studio: floor, backdrop, person) is on screen;
    # the viewer's UI itself is near-white or near-black
    grey = img.mean(axis=2)
    mid = ((grey > 40) & (grey < 200)).mean()
    return {"cue overlays": bool(yellow > 30), "camera images": bool(mid > 0.03)}


def test_served_web_viewer_shows_the_service(chromium, tmp_path, tmp_path_factory, data_dir):
    walk = small_recording(tmp_path_factory.getbasetemp(), data_dir)
    web, grpc = free_port(), free_port()
    # one pass of the replay (the sync then stops; the viewer keeps serving what it logged):
    # a software-rendered page on a loaded host falls minutes behind an endless live stream
    cfg = RunConfig(rig_path=walk / "rig.toml", source=f"replay:{walk}", duration_s=None,
                    rerun=f"serve:{web}:{grpc}", preview_every=PREVIEW_EVERY, status_line=False, log_dir=tmp_path / "logs")
    L = Launcher(cfg)
    browser = None
    try:
        L.start()
        assert wait_for(lambda: len(L.monitor.poses) > 30, WAIT_S, L), "no poses"
        # everything the viewer serves listens on loopback only (the web server, a low-priority
        # child of the viewer, may still be starting)
        viewer = psutil.Process(L.pid("viewer"))

        def served():
            socks = _listening([viewer.pid] + [c.pid for c in viewer.children(recursive=True)])
            return socks if (("127.0.0.1", web) in socks) and (("127.0.0.1", grpc) in socks) else None
        socks = wait_for(served, WAIT_S, L)
        assert socks, _listening([viewer.pid] + [c.pid for c in viewer.children(recursive=True)])
        assert all(ip == "127.0.0.1" for ip, _ in socks), socks

        browser = HeadlessChromium(chromium, size=(1400, 900), user_dir=tmp_path / "chromium")
        tab = browser.open(web_viewer_url(web, grpc))
        # the page downloads and compiles the viewer (WebAssembly, software rendering: tens of
        # seconds on a loaded machine), then streams: look until it shows the service
        t_end, found = time.monotonic() + VIEWER_WAIT_S, None
        while found is None or not all(found.values()):
            assert time.monotonic() < t_end, f"after {VIEWER_WAIT_S:.0f} s the web viewer shows {found} " \
                                             f"(screenshot {tmp_path / 'web_viewer.png'})"
            L.supervise_for(SHOT_EVERY_S)
            png = browser.capture(tab)
            (tmp_path / "web_viewer.png").write_bytes(png)
            found = _shows_the_service(png)
        print(f"screenshot: {tmp_path / 'web_viewer.png'}: {found}")
    finally:
        if browser is not None:
            browser.close()
        L.stop()
