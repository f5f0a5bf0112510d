"""``--rerun serve``: the web viewer on 127.0.0.1 shows the running service in headless Chromium."""

import shutil

import cv2
import numpy as np
import psutil
import pytest
from service_helpers import HeadlessChromium, small_recording, wait_for

from nodes.launcher import Launcher, RunConfig, free_port
from nodes.viewer import web_viewer_url

pytestmark = pytest.mark.slow

VIEWER_WAIT_S = 25.0      # wasm download + compile + first data, software rendering
PREVIEW_EVERY = 6         # fewer images: the software-rendered browser keeps up better


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


def test_served_web_viewer_shows_the_service(chromium, tmp_path, tmp_path_factory, data_dir):
    walk = small_recording(tmp_path_factory.getbasetemp(), data_dir)
    web, grpc = free_port(), free_port()
    cfg = RunConfig(rig_path=walk / "rig.toml", source=f"replay:{walk}", duration_s=600.0,
                    rerun=f"serve:{web}:{grpc}", preview_every=PREVIEW_EVERY, status_line=False, log_dir=tmp_path / "logs")
    L = Launcher(cfg)
    browser = None
    try:
        L.start()
        assert wait_for(lambda: len(L.monitor.poses) > 30, 30, L), "no poses"
        # everything the viewer serves listens on loopback only (the web server, a low-priority
        # child of the viewer, may still be starting)
        viewer = psutil.Process(L.pid("viewer"))

        def served():
            socks = _listening([viewer.pid] + [c.pid for c in viewer.children(recursive=True)])
            return socks if (("127.0.0.1", web) in socks) and (("127.0.0.1", grpc) in socks) else None
        socks = wait_for(served, 30, L)
        assert socks, _listening([viewer.pid] + [c.pid for c in viewer.children(recursive=True)])
        assert all(ip == "127.0.0.1" for ip, _ in socks), socks

        browser = HeadlessChromium(chromium, size=(1400, 900), user_dir=tmp_path / "chromium")
        png = browser.screenshot(web_viewer_url(web, grpc), wait_s=VIEWER_WAIT_S)
        (tmp_path / "web_viewer.png").write_bytes(png)
        print(f"screenshot: {tmp_path / 'web_viewer.png'}")
        img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        assert img is not None and img.shape[1] == 1400
        # the head cue's ellipse/point (yellow, BGR ~ (0, 220, 255)) is drawn over the cameras
        yellow = ((img[..., 2] > 200) & (img[..., 1] > 170) & (img[..., 0] < 90)).sum()
        assert yellow > 30, f"{yellow} yellow pixels: no cue overlays"
        # at least one camera image (mid-tone studio: floor, backdrop, person) is on screen;
        # the viewer's UI itself is near-white or near-black
        grey = img.mean(axis=2)
        mid = ((grey > 40) & (grey < 200)).mean()
        assert mid > 0.03, f"only {mid:.1%} mid-tone pixels: no camera image shown"
        # the 3D view shows the skeleton's joints (light blue-violet, BGR ~ (255, 200, 200))
        joints = ((img[..., 0] > 220) & (np.abs(img[..., 1].astype(int) - 200) < 30)
                  & (np.abs(img[..., 2].astype(int) - 200) < 30)).sum()
        print(f"yellow {yellow} px, mid-tone {mid:.1%}, joint-coloured {joints} px")
    finally:
        if browser is not None:
            browser.close()
        L.stop()
