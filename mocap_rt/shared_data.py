"""Where the project's shared data lives (recorded motion, markers, video: ``../shared/data``).

``data_root()``: ``$MOCAP_RT_DATA`` when set and not empty, else ``DEFAULT_DATA``, the
``shared/data`` folder beside the checkout (README). Standard library only: the warm-up's
cache check (``warmup.is_warm``) asks it without importing numba.
"""

from __future__ import annotations

import os
from pathlib import Path

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def data_root() -> Path:
    """The shared data directory (module doc), resolved."""
    return Path(os.environ.get("MOCAP_RT_DATA") or DEFAULT_DATA).resolve()
