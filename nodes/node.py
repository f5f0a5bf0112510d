"""How a node process starts: its typed settings (flags, or ``--config FILE``) and ``run_node``.

Every node declares its settings once, as a frozen dataclass deriving from ``NodeSettings``
(the defaults live there and nowhere else); its flags fill it, and ``--config FILE`` reads it
from a TOML file (``mocap_rt.config.load_dataclass``; flags given as well win over the file).
``run_node`` is the one ``main`` of the six nodes: logging, rig, Zenoh session, warm-up,
real-time priority, ``ready``, the node's loop, ``stopping``.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import re
import sys
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, TypeVar

from mocap_rt.config import coerce_paths
from nodes.transport import add_zenoh_args

DEFAULT_FPS = 30.0          # a rig's frame rate when its metadata has none

S = TypeVar("S", bound="NodeSettings")


@dataclass(frozen=True)
class NodeSettings:
    """What every node is given.

    rig : the rig calibration TOML; rig_name : its key-expression name (default: the rig's
    ``[metadata] name`` or file stem); node : the name in status messages; rt_priority :
    SCHED_FIFO priority once warmed up (0 = normal scheduling); listen / connect /
    zenoh_config / shm : the Zenoh session (``nodes/transport.py``).
    """

    rig: Path | None = None
    rig_name: str | None = None
    node: str = ""
    log_level: str = "INFO"
    rt_priority: int = 0
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    zenoh_config: Path | None = None
    shm: bool = False

    def __post_init__(self) -> None:
        coerce_paths(self)          # every Path field, the subclasses' too
        for name in ("listen", "connect"):
            object.__setattr__(self, name, tuple(getattr(self, name) or ()))
        if not 0 <= self.rt_priority <= 99:
            raise ValueError(f"rt_priority must be in 0..99, got {self.rt_priority}")


def base_parser(description: str) -> argparse.ArgumentParser:
    """The flags of ``NodeSettings`` and ``--config``; a node adds its own (defaults: ``parse_settings``)."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--config", type=Path, default=None, metavar="FILE.toml",
                   help="the node's settings as TOML (keys = the long flags with '_' for '-'); "
                        "flags given as well win")
    p.add_argument("--rig", type=Path, help="rig calibration TOML (required, here or in --config)")
    p.add_argument("--rig-name", help="key-expression name (default: from the rig)")
    p.add_argument("--node", help="node name in status messages")
    p.add_argument("--log-level")
    p.add_argument("--rt-priority", type=int,
                   help="once warmed up, run every thread of this node SCHED_FIFO at this priority "
                        "(1-99; 0 = normal scheduling; needs root or CAP_SYS_NICE)")
    add_zenoh_args(p)
    return p


def settings_parser(cls: type[NodeSettings], description: str, add_flags: Callable | None = None):
    """``base_parser`` plus the node's own flags (``add_flags(parser)``), with the defaults of
    ``cls`` (what ``parse_args`` gives without ``--config``)."""
    p = base_parser(description)
    if add_flags is not None:
        add_flags(p)
    _set_defaults(p, cls())
    return p


def _set_defaults(parser: argparse.ArgumentParser, settings: NodeSettings) -> None:
    values = {f.name: getattr(settings, f.name) for f in dataclasses.fields(settings)}
    for a in parser._actions:       # repeatable flags start empty: the file's list is used when none is given
        if isinstance(a, argparse._AppendAction):
            values[a.dest] = None
    parser.set_defaults(**{k: v for k, v in values.items() if k in {a.dest for a in parser._actions}})


def parse_settings(parser: argparse.ArgumentParser, cls: type[S], argv: list[str] | None = None) -> S:
    """The node's settings: ``cls`` defaults, then ``--config FILE``, then the flags given.
    A bad file or value ends the process with one ``error:`` line naming it (exit code 2)."""
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--config", type=Path, default=None)
    known, _ = pre.parse_known_args(argv)
    base = cls()
    if known.config is not None:
        from mocap_rt.config import load_dataclass

        try:
            base = load_dataclass(cls, known.config)
        except (ValueError, OSError) as exc:      # FileFormatError is a ValueError
            parser.error(f"--config {known.config}: {exc}")
    _set_defaults(parser, base)
    ns = parser.parse_args(argv)
    values: dict[str, Any] = {f.name: getattr(ns, f.name, getattr(base, f.name)) for f in dataclasses.fields(cls)}
    for name in ("listen", "connect"):        # repeatable flags: the file's list unless given
        if values[name] is None:
            values[name] = getattr(base, name)
    try:
        settings = cls(**values)
    except ValueError as exc:
        parser.error(str(exc))
    if settings.rig is None:
        parser.error("--rig is required (or rig = ... in --config)")
    return settings


def setup_logging(level: str) -> None:
    logging.basicConfig(level=getattr(logging, str(level).upper(), logging.INFO),
                        format="%(asctime)s %(levelname)s %(name)s[%(process)d]: %(message)s")


def rig_name_for(rig_path: Path, rig) -> str:
    """The rig's key-expression name: ``[metadata] name`` or the file stem, sanitised."""
    raw = str(rig.metadata.get("name") or Path(rig_path).stem)
    return re.sub(r"[^A-Za-z0-9_.\-]", "_", raw)[:64] or "rig"


def rig_fps(rig) -> float:
    """The rig's frame rate: ``[metadata] fps``, else ``DEFAULT_FPS``."""
    return float(rig.metadata.get("fps", DEFAULT_FPS))


def run_node(role: str, settings: NodeSettings, serve: Callable, *, prepare: Callable | None = None,
             setup: Callable | None = None, node: str | None = None) -> int:
    """Run one node process to its end; returns the exit code.

    ``prepare(rig, stack) -> state``: checks and resources before joining the service (``stack``
    closes what it opens). A bad rig or input (``ValueError``/``OSError`` while reading the rig
    or in ``prepare``) is one ``ROLE: error: ...`` line and exit code 2, before any message. In the session
    (``nodes.runtime.node_session``: status "starting", kernels loaded): ``setup(rt, rig,
    state) -> state`` (warm-up), then the real-time priority, status "ready", ``serve(rt, rig, state)``
    until ``rt.stop``, status "stopping". ``node``: the status name (default ``settings.node``).
    """
    from mocap_rt.geometry.rig import read_rig
    from nodes.runtime import node_session

    setup_logging(settings.log_level)
    with ExitStack() as stack:
        try:
            rig = read_rig(settings.rig)
            state = prepare(rig, stack) if prepare is not None else None
        except (ValueError, OSError) as exc:       # a bad input: one line naming it, before joining
            print(f"{role}: error: {exc}", file=sys.stderr)
            return 2
        rig_name = settings.rig_name or rig_name_for(settings.rig, rig)
        with node_session(settings, rig_name, role, node or settings.node) as rt:
            if setup is not None:
                state = setup(rt, rig, state)
            rt.enter_realtime(settings.rt_priority)
            rt.publish_status("ready", force=True)
            serve(rt, rig, state)
            rt.publish_status("stopping", force=True)
    return 0
