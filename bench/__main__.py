"""Run every ``bench/bench_*.py`` (or those named) and print their tables.

Each module has ``main(argv: list[str] | None = None) -> int``. Options after the names
(``python -m bench body_suite --quick``) are passed to every bench named.

The numba kernel cache is warmed first when its stamp is stale (``mocap_rt.warmup``, in a
process of its own): numba notices a changed kernel but not a changed callee in another
file, so a bench run after an edit would otherwise time or score the old code.
"""

import importlib
import pkgutil
import subprocess
import sys
import time
from pathlib import Path


def main(argv: list[str]) -> int:
    here = Path(__file__).parent
    names = sorted(m.name for m in pkgutil.iter_modules([str(here)]) if m.name.startswith("bench_"))
    first_opt = next((i for i, a in enumerate(argv) if a.startswith("-")), len(argv))
    wanted, options = argv[:first_opt], argv[first_opt:]
    if wanted:
        names = [n for n in names if any(w in n for w in wanted)]
    from mocap_rt.warmup import is_warm

    if not is_warm():
        subprocess.run([sys.executable, "-m", "mocap_rt.warmup"], check=True)
    status = 0
    for name in names:
        print(f"\n===== {name} =====", flush=True)
        t0 = time.perf_counter()
        status |= int(importlib.import_module(f"bench.{name}").main(list(options)) or 0)
        print(f"({name}: {time.perf_counter() - t0:.1f} s)", flush=True)
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
