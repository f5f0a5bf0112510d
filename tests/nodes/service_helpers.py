"""Helpers for the service tests: a small studio recording, a probe session, waiting."""

from __future__ import annotations

import time
from pathlib import Path

WALK_CLIP = "bvh/cmu/cmu_02_01_walk.bvh"


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
