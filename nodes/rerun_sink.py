"""Where the viewer's Rerun stream goes (``--rerun``): a file, a served web viewer, a native viewer.

``save:FILE.rrd`` writes a file; ``serve[:WEB_PORT[:GRPC_PORT]]`` keeps a gRPC server bound to
127.0.0.1 and hosts the web viewer on 127.0.0.1 (``rerun --serve-web --bind 127.0.0.1``);
``spawn`` starts the native viewer (needs a display); ``connect:URL`` streams to a running viewer.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

from nodes.procs import die_with_parent

log = logging.getLogger(__name__)

DEFAULT_WEB_PORT = 9090
DEFAULT_GRPC_PORT = 9876
SERVE_MEMORY_LIMIT = "64MiB"    # history kept for late web viewers (~1.5 min of a 640x480 demo)


def parse_rerun(spec: str) -> tuple[str, list[str]]:
    """``"save:x.rrd"`` -> ``("save", ["x.rrd"])``; ``"serve:9090:9876"`` -> ports."""
    mode, _, rest = str(spec).partition(":")
    if mode == "save" and rest:
        return mode, [rest]
    if mode == "serve":
        ports = [p for p in rest.split(":") if p] if rest else []
        if len(ports) > 2 or not all(p.isdigit() for p in ports):
            raise ValueError(f"--rerun {spec!r}: expected serve[:WEB_PORT[:GRPC_PORT]]")
        return mode, ports
    if mode == "spawn" and not rest:
        return mode, []
    if mode == "connect" and rest:
        return mode, [rest]
    raise ValueError(f"--rerun {spec!r}: expected save:FILE.rrd | serve[:WEB[:GRPC]] | spawn | connect:URL")


def check_rerun(spec: str) -> tuple[str, list[str]]:
    """``parse_rerun``, and ``spawn`` only with a display (ValueError naming the flag)."""
    mode, args = parse_rerun(spec)
    if mode == "spawn" and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ValueError("--rerun spawn needs a display (DISPLAY/WAYLAND_DISPLAY unset); "
                         "use --rerun save:FILE.rrd or serve")
    return mode, args


def start_sink(spec: str, app_id: str = "mocap_rt") -> subprocess.Popen | None:
    """Initialise Rerun for ``--rerun spec``; returns the web-viewer process for ``serve``."""
    import rerun as rr

    mode, args = check_rerun(spec)
    rr.init(app_id, spawn=False)
    if mode == "save":
        Path(args[0]).parent.mkdir(parents=True, exist_ok=True)
        rr.save(args[0])
        return None
    if mode == "connect":
        rr.connect_grpc(args[0])
        return None
    if mode == "spawn":
        rr.spawn()
        return None
    web = int(args[0]) if args else DEFAULT_WEB_PORT
    grpc = int(args[1]) if len(args) > 1 else DEFAULT_GRPC_PORT
    # a browser that connects late gets the newest data first and at most SERVE_MEMORY_LIMIT of
    # history (the whole run, replayed into a software-rendered page, kept it at "No data")
    rr.set_sinks(rr.GrpcServerSink(bind_ip="127.0.0.1", port=grpc, server_memory_limit=SERVE_MEMORY_LIMIT,
                                   newest_first=True))
    url = f"rerun+http://127.0.0.1:{grpc}/proxy"
    exe = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
    if exe is None:
        raise FileNotFoundError("the 'rerun' executable (from rerun-sdk) is needed to host the web viewer")
    # dies with the viewer, whatever ends it (the launcher also kills the viewer's process group)
    proc = subprocess.Popen([exe, "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", str(web), url],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL,
                            preexec_fn=die_with_parent)
    log.info("viewer: open %s", web_viewer_url(web, grpc))
    return proc


def web_viewer_url(web_port: int, grpc_port: int) -> str:
    from urllib.parse import quote

    return f"http://127.0.0.1:{web_port}/?url={quote(f'rerun+http://127.0.0.1:{grpc_port}/proxy', safe='')}"
