"""A node stand-in for the fork server's tests: ``python -m fork_probe MODE [ARG]``.

echo CODE : print its argv, one line of stdin and how many kernel signatures it holds
            without having loaded any; exit CODE.
crash     : raise (the traceback goes to its log).
sleep     : say so, then sleep until killed.
quick CODE: as a frame-path node (``QUICK_EXIT``): an exit handler and an object's finaliser
            each print a line; exit CODE (an int, or a message: exit 1).
"""

import atexit
import json
import os
import sys
import time

QUICK_EXIT = True       # read by the fork server (nodes.forkserver._quick_exit)


class _Finalised:
    def __del__(self):
        print("finaliser ran", flush=True)


def main() -> int:
    mode = sys.argv[1]
    if mode == "echo":
        from mocap_rt.warmup import cached_dispatchers

        held = sum(len(d.signatures) for d in cached_dispatchers())
        print(json.dumps({"argv": sys.argv[1:], "stdin": sys.stdin.readline().strip(), "held": held,
                          "sid": os.getsid(0), "pid": os.getpid(), "nice": os.nice(0)}), flush=True)
        return int(sys.argv[2])
    if mode == "quick":
        sys.modules[__name__].kept = _Finalised()               # alive until the interpreter's teardown
        atexit.register(lambda: print("exit handler ran"))       # flushed by the quick exit
        code = sys.argv[2]
        return int(code) if code.isdigit() else code
    if mode == "crash":
        raise RuntimeError("the probe crashed on purpose")
    print("sleeping", flush=True)
    time.sleep(600)
    return 0


if __name__ == "__main__":
    sys.exit(main())
