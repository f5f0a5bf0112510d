"""The hot spare: one camera worker kept warm and idle, which replaces a worker that died.

The spare is ``camera_worker --standby`` with the first camera's flags, at a low priority
(``BACKGROUND_NICE``): it loads every kernel by warming up, then waits for one JSON line on
stdin naming the worker it becomes. A dead worker is so back within a fraction of a second
instead of a process start; a new spare is started at once.
"""

from __future__ import annotations

import json
import logging
import subprocess

from nodes.procs import renice, stop_all
from nodes.run_config import NodeProc
from nodes.supervisor import STOP_TIMEOUT_S, Supervisor

log = logging.getLogger(__name__)


class HotSpare:
    """The spare worker of a ``Supervisor`` (``proc``: its process, None when there is none)."""

    def __init__(self, sup: Supervisor) -> None:
        self.sup = sup
        self.proc: subprocess.Popen | None = None

    def start(self) -> None:
        """Start a spare on the first camera's flags (not when nodes are not restarted)."""
        first = next((n for n in self.sup.nodes.values() if n.role == "camera"), None)
        if first is not None and self.sup.restart:
            self.proc = self.sup.popen(first.argv + ["--standby"], "spare", "spare", stdin=subprocess.PIPE)

    def take_over(self, node: NodeProc) -> bool:
        """Hand ``node``'s flags to the spare; False if there is none (or it is gone)."""
        spare, self.proc = self.proc, None
        if spare is None:
            return False
        if spare.poll() is not None:
            log.warning("the hot spare had exited with %s%s", spare.returncode, self.sup.log_tail("spare"))
            self.start()
            return False
        job = {"argv": node.argv[2:], "log": str(self.sup.log_path(node.name))}    # after "-m module"
        if not renice(spare.pid, self.sup.nice_of(node.role)):
            log.warning("the hot spare's priority could not be raised to nice %d", self.sup.nice_of(node.role))
        try:
            spare.stdin.write((json.dumps(job) + "\n").encode())
            spare.stdin.close()
        except OSError:
            spare.kill()
            return False
        node.proc = spare
        node.cpu_last_s = 0.0
        log.info("%s: taken over by the hot spare (pid %d)", node.name, spare.pid)
        self.start()
        return True

    def stop(self) -> None:
        spare, self.proc = self.proc, None
        if spare is None:
            return
        try:
            spare.stdin.close()           # end of input: a waiting spare exits
        except OSError:
            pass
        stop_all([("hot spare", spare)], STOP_TIMEOUT_S)
