"""Run every ``bench/bench_*.py`` (or those named) and print their tables.

Each module has ``main(argv: list[str] | None = None) -> int``. Options after the names
(``python -m bench body_suite --quick``) are passed to every bench named.
"""

import importlib
import pkgutil
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
    status = 0
    for name in names:
        print(f"\n===== {name} =====", flush=True)
        t0 = time.perf_counter()
        status |= int(importlib.import_module(f"bench.{name}").main(list(options)) or 0)
        print(f"({name}: {time.perf_counter() - t0:.1f} s)", flush=True)
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
