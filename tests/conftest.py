"""Shared fixtures: the real data lives in ../shared/data (MOCAP_RT_DATA overrides)."""

import os
from pathlib import Path

import pytest

from mocap_rt.shared_data import data_root

REPO = Path(__file__).resolve().parents[1]
SERVICE_TESTS = "service clusters"  # the xdist work unit of the modules that start whole clusters:
SERVICE_MODULES = tuple(f"tests/nodes/test_nodes_{m}.py::" for m in (
    "faults", "forged", "gst", "lifecycle", "netns", "replay_run", "service", "viewer_web"))
LIBRARY_NICENESS = 10               # of a library test beside a service cluster (``make test``, -n 2)


@pytest.fixture(scope="session")
def data_dir() -> Path:
    root = data_root()
    if not root.is_dir():
        pytest.fail(f"shared data not found at {root} (set MOCAP_RT_DATA)")
    return root


@pytest.fixture(scope="session")
def warm_kernels() -> dict:
    """Every numba kernel compiled once for the session before any test starts nodes that
    would otherwise compile them at once (``python -m mocap_rt.warmup``; a no-op when the
    cache's stamp matches the kernel sources). In a child process: this one has usually run
    the kernels already (library tests), and numba does not write the cache of a kernel that
    is already compiled in memory, so a warm-up here would stamp an empty cache as warm and
    every node would compile on its own."""
    import subprocess
    import sys

    from mocap_rt.warmup import DEFAULT_CLIP, read_stamp

    clip = data_root() / DEFAULT_CLIP
    argv = [sys.executable, "-m", "mocap_rt.warmup"] + (["--motion", str(clip)] if clip.is_file() else [])
    out = subprocess.run(argv, capture_output=True, text=True, timeout=1200, cwd=REPO)
    assert out.returncode == 0, f"kernel warm-up failed: {out.stdout[-2000:]}{out.stderr[-2000:]}"
    return read_stamp()


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """Under ``-n 2`` (``make test``): the modules that start whole clusters are ONE work unit,
    handed out first, so one worker runs the clusters one after another while the other takes
    the rest, module by module (two clusters at once on 2 cores lose frames)."""
    from xdist.scheduler import LoadScopeScheduling

    class ServicesApart(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return SERVICE_TESTS if nodeid.startswith(SERVICE_MODULES) else super()._split_scope(nodeid)

        def _assign_work_unit(self, node) -> None:
            if SERVICE_TESTS in self.workqueue:
                self.workqueue.move_to_end(SERVICE_TESTS, last=False)
            super()._assign_work_unit(node)

    return ServicesApart(config, log)


def pytest_runtest_setup(item):
    """Beside a service cluster (an xdist worker), the other tests run at a lower priority: the
    cluster's frame path keeps its core (a cluster's test asks for its own back; only root may)."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        service = item.nodeid.startswith(SERVICE_MODULES)
        try:
            os.setpriority(os.PRIO_PROCESS, 0, 0 if service else LIBRARY_NICENESS)
        except PermissionError:
            pass
