"""Shared by the crash-safety tests of the writers."""

import os
import signal
import subprocess
import sys

import pytest


def _kill_when_ready(script: str) -> None:
    """Run ``script`` in a fresh interpreter; SIGKILL it once it prints ``ready``."""
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)


@pytest.fixture
def kill_when_ready():
    return _kill_when_ready
