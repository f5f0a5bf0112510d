"""Output files that are never lost: atomic writes, no output over an input, no silent overwrite.

* ``atomic_write(path)``: write to a temporary name in the same folder, flush and fsync, then
  rename over ``path``; on an exception the temporary file is removed and ``path`` is untouched.
  A crash or a failed run so never leaves a half-written output, nor destroys the old one.
* ``refuse_input_as_output(out, inputs)``: an output that would replace one of the inputs (the
  same file, by resolved path or ``os.path.samefile``) is an ``OutputError``.
* ``claim_outputs(paths, overwrite)``: outputs left by an earlier run are an ``OutputError``
  unless ``overwrite``.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path


class OutputError(ValueError):
    """An output that would destroy an input or an earlier result; the message names it."""


@contextmanager
def atomic_write(path: str | Path, mode: str = "w", encoding: str | None = "utf-8") -> Iterator:
    """Open a temporary file beside ``path`` for writing (``mode`` "w" or "wb"); on a clean
    exit it is flushed, fsynced and renamed over ``path``, else removed."""
    path = Path(path)
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_write mode must be 'w' or 'wb', got {mode!r}")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": encoding, "newline": ""})) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: str | Path, text: str) -> None:
    """``Path.write_text`` that never leaves a half-written file."""
    with atomic_write(path) as fh:
        fh.write(text)


def same_file(a: str | Path, b: str | Path) -> bool:
    """True when ``a`` and ``b`` name one file (or one path, if either does not exist yet)."""
    a, b = Path(a), Path(b)
    try:
        return os.path.samefile(a, b)
    except OSError:
        return a.resolve() == b.resolve()


def refuse_input_as_output(out: str | Path, inputs: Iterable[str | Path], what: str = "--out") -> None:
    """``OutputError`` if ``out`` is one of ``inputs`` (the input would be destroyed)."""
    for src in inputs:
        if src is not None and same_file(out, src):
            raise OutputError(f"{what} {out} is the input {src}; writing it would destroy the input "
                              f"(choose another output)")


def claim_outputs(paths: Iterable[str | Path], overwrite: bool, what: str = "--out") -> None:
    """``OutputError`` naming the first of ``paths`` that exists, unless ``overwrite``."""
    if overwrite:
        return
    for p in paths:
        if Path(p).exists():
            raise OutputError(f"{what}: {p} exists (an earlier run's result); pass --overwrite to replace it "
                              f"or choose another {what}")
