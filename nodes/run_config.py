"""What ``mocap-rt run`` was asked to do (``RunConfig``) and one supervised node process (``NodeProc``)."""

from __future__ import annotations

import subprocess
from dataclasses import dataclass, field
from pathlib import Path

from mocap_rt.config import coerce_paths
from mocap_rt.fusion.gather import DEFAULT_DEADLINE_FRAC


@dataclass(frozen=True)
class RunConfig:
    """Everything ``mocap-rt run`` was asked to do (see ``nodes/cli.py`` for the flags; ``mocap-rt
    run --config FILE`` reads these fields from TOML). ``rig_path`` None: the recording's
    ``rig.toml`` (replay/fake sources, ``nodes.preflight.rig_path_for``)."""

    rig_path: Path | None = None
    source: str = ""
    speed: float | None = 1.0          # None = as fast as possible (free-running sync)
    duration_s: float | None = None
    rerun: str | None = None
    record: Path | None = None
    stats: Path | None = None
    rig_name: str | None = None
    deadline_frac: float = DEFAULT_DEADLINE_FRAC
    bones: Path | None = None          # the subject's bone lengths TOML (default: estimated live)
    preview_every: int | None = None
    restart: bool = True
    log_dir: Path | None = None
    status_line: bool = True
    fps: float | None = None           # override the trigger base rate
    nice: int = 0                      # niceness of sync, workers, fusion (negative: higher priority)
    rt_priority: int | None = None     # SCHED_FIFO priority of workers and fusion (sync +2)
                                       # once warmed up; 0 = off; None = auto (DEFAULT_RT_PRIORITY
                                       # at a triggered rate, off when free-running)
    extra_node_args: dict = field(default_factory=dict)   # node role -> extra argv
    stream: str | None = None          # pose stream, e.g. "vmc:127.0.0.1:39539" (nodes/streamer.py)
    allow_remote_stream: bool = False  # let the stream leave this host
    backgrounds_from: Path | None = None   # gst: sources: a recording's stored backgrounds
    overwrite: bool = False            # replace an existing --stats / --rerun save: file

    def __post_init__(self) -> None:
        coerce_paths(self)


@dataclass
class NodeProc:
    """One supervised node process."""

    name: str
    role: str
    argv: list[str]
    port: int
    proc: subprocess.Popen | None = None   # or a nodes.forkserver.ForkedProc (the same methods)
    restarts: int = 0
    cpu_done_s: float = 0.0            # CPU of earlier (dead) instances
    cpu_last_s: float = 0.0            # CPU of the current instance, last seen
    finished: bool = False             # exited on its own with code 0 (sync at end of replay)

    @property
    def cpu_s(self) -> float:
        return self.cpu_done_s + self.cpu_last_s
