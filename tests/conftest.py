"""Shared fixtures: the real data lives in ../shared/data (MOCAP_RT_DATA overrides)."""

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def data_root() -> Path:
    return Path(os.environ.get("MOCAP_RT_DATA", REPO.parent / "shared" / "data")).resolve()


@pytest.fixture(scope="session")
def data_dir() -> Path:
    root = data_root()
    if not root.is_dir():
        pytest.fail(f"shared data not found at {root} (set MOCAP_RT_DATA)")
    return root


@pytest.fixture(scope="session")
def warm_kernels() -> dict:
    """Every numba kernel compiled once for the session, in this process, before any test
    starts nodes that would otherwise compile them at once (``mocap_rt.warmup``; a no-op
    when the cache's stamp matches the kernel sources)."""
    from mocap_rt.warmup import DEFAULT_CLIP, ensure_warm

    clip = data_root() / DEFAULT_CLIP
    return ensure_warm(clip if clip.is_file() else None)
