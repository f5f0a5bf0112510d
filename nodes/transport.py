"""The one place where Zenoh sessions are configured: the same flags for every node.

Zenoh's defaults are unsafe here (a default peer listens on every interface and scouts by
multicast): every session is a *peer* with explicit listen endpoints (loopback unless told
otherwise), multicast and gossip scouting off, and connects only to explicit endpoints,
retrying so that nodes may start in any order and a restarted node is re-joined.
"""

from __future__ import annotations

import argparse
import json
import logging
from collections.abc import Sequence
from pathlib import Path

log = logging.getLogger(__name__)

DEFAULT_LISTEN = "tcp/127.0.0.1:0"   # loopback, ephemeral port
RETRY_PERIOD_INIT_MS = 100           # first reconnect attempt to a missing peer
RETRY_PERIOD_MAX_MS = 500            # so a restarted node is found again within ~0.5 s


def add_zenoh_args(parser: argparse.ArgumentParser) -> None:
    """Add ``--listen``, ``--connect``, ``--zenoh-config`` and ``--shm`` to a node's parser."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                   help=f"endpoint to listen on, repeatable (default {DEFAULT_LISTEN})")
    g.add_argument("--connect", action="append", default=None, metavar="ENDPOINT",
                   help="peer endpoint to connect to, repeatable (e.g. tcp/127.0.0.1:7450)")
    g.add_argument("--zenoh-config", type=Path, default=None, metavar="FILE.json5",
                   help="extra Zenoh settings (TLS, access control) applied after these flags")
    g.add_argument("--shm", action="store_true",
                   help="enable Zenoh shared-memory transport (same host only)")


def make_config(listen: Sequence[str] | None = None, connect: Sequence[str] | None = None,
                config_file: Path | None = None, shared_memory: bool = False):
    """A ``zenoh.Config`` for a peer with explicit endpoints and no scouting."""
    import zenoh

    if config_file is not None and not Path(config_file).is_file():
        raise FileNotFoundError(f"--zenoh-config {config_file}: no such file")
    conf = zenoh.Config.from_file(str(config_file)) if config_file else zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    # flags win; without flags a config file keeps its own endpoints; else loopback only
    if listen or not config_file:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen) if listen else [DEFAULT_LISTEN]))
    if connect or not config_file:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect) if connect else []))
    # keep retrying absent or lost peers in the background (a restarted peer is re-joined);
    # opening does not fail on them (exit_on_failure false)
    conf.insert_json5("connect/timeout_ms", "-1")
    conf.insert_json5("connect/exit_on_failure", "false")
    conf.insert_json5("connect/retry", json.dumps({
        "period_init_ms": RETRY_PERIOD_INIT_MS, "period_max_ms": RETRY_PERIOD_MAX_MS,
        "period_increase_factor": 1.5}))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    conf.insert_json5("transport/shared_memory/enabled", "true" if shared_memory else "false")
    return conf


def direct_callback(fn):
    """A subscriber handler that runs ``fn`` on Zenoh's receiving thread itself (zenoh-python's
    ``Callback(indirect=False)``) instead of handing each sample to a separate Python thread:
    one thread wake-up less between a message's arrival and the node's reaction. ``fn``
    must be short and must not block (decode, then hand over to the node's own thread)."""
    import zenoh

    return zenoh.handlers.Callback(fn, indirect=False)


def open_session(settings):
    """Open a Zenoh session from ``listen``, ``connect``, ``zenoh_config`` and ``shm`` of
    ``settings`` (a node's ``NodeSettings``, or the flags of ``add_zenoh_args``)."""
    import zenoh

    conf = make_config(settings.listen, settings.connect, settings.zenoh_config, settings.shm)
    session = zenoh.open(conf)
    log.debug("zenoh session %s listen=%s connect=%s", session.info.zid(), settings.listen, settings.connect)
    return session


def zenoh_argv(listen: Sequence[str], connect: Sequence[str], shared_memory: bool = False) -> list[str]:
    """The command-line flags that reproduce these endpoints (used by the launcher)."""
    argv: list[str] = []
    for e in listen:
        argv += ["--listen", e]
    for e in connect:
        argv += ["--connect", e]
    if shared_memory:
        argv.append("--shm")
    return argv
