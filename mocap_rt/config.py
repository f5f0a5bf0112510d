"""The project's TOML files: one reader, one writer, and settings dataclasses loaded from them.

Owns ``read_toml`` / ``loads_toml`` (parse, errors name the file), ``dumps_toml`` (the
writer every module uses; floats as ``repr`` so reading back gives the same bits),
``load_dataclass`` / ``dataclass_from_dict`` (a frozen settings
dataclass from a table, unknown keys and wrong types are errors naming file and key) and
``FileFormatError``, the base class of every "this input file is malformed" error.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

T = TypeVar("T")


class FileFormatError(ValueError):
    """An input file (or message) that cannot be used; the message names the file and field.

    Every reader's own error class (``RigFileError``, ``RecordingError``, ``ColourModelError``,
    ``SegmentError``, ``SkeletonMapError``, ``BvhError``, ``MarkerFileError``) derives from it;
    it is a ``ValueError``, which the command line turns into one ``error:`` line.
    """


# ----------------------------------------------------------------------------- reading
def loads_toml(text: str, where: str, error: type[FileFormatError] = FileFormatError) -> dict:
    """Parse TOML text; ``error("{where}: not valid TOML: ...")`` when it is not."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{where}: not valid TOML: {exc}") from None


def read_toml(path: str | Path, what: str = "TOML file",
              error: type[FileFormatError] = FileFormatError) -> dict:
    """Parse the TOML file ``path``.

    A missing file raises ``FileNotFoundError("{path}: no such {what}")``; text that is not
    TOML raises ``error("{path}: not valid TOML: ...")``.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (FileNotFoundError, IsADirectoryError):
        raise FileNotFoundError(f"{path}: no such {what}") from None
    return loads_toml(text, str(path), error)


# ----------------------------------------------------------------------------- writing
_ESCAPES = {"\\": "\\\\", '"': '\\"', "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}


def _escape(ch: str) -> str:
    """One character of a TOML basic string (control characters as escapes)."""
    if ch in _ESCAPES:
        return _ESCAPES[ch]
    return f"\\u{ord(ch):04x}" if ch < " " or ch == "\x7f" else ch


def _fmt(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(value, str):
        return '"' + "".join(_escape(ch) for ch in value) + '"'
    if isinstance(value, np.ndarray):
        return _fmt(value.tolist())
    if isinstance(value, (list, tuple)):
        return "[ " + ", ".join(_fmt(v) for v in value) + "]"
    if isinstance(value, dict):                        # an inline table (inside a list)
        return "{ " + ", ".join(f"{k} = {_fmt(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def dumps_toml(tables: dict[str, dict]) -> str:
    """TOML text of a dict of tables. Values: scalars, strings, (nested) lists and arrays,
    or dicts (written as sub-tables ``[table.key]`` after the table's own values)."""
    lines: list[str] = []
    for table, entries in tables.items():
        lines.append(f"[{table}]")
        subtables = {}
        for key, value in entries.items():
            if isinstance(value, dict):
                subtables[f"{table}.{key}"] = value
            else:
                lines.append(f"{key} = {_fmt(value)}")
        lines.append("")
        if subtables:
            lines.append(dumps_toml(subtables))
    return "\n".join(lines)


def dataclass_to_dict(obj) -> dict:
    """Fields of a settings dataclass as a dict for ``dumps_toml`` (nested dataclasses as
    dicts, None fields left out: ``load_dataclass`` gives them their default)."""
    out = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if v is None:
            continue
        if dataclasses.is_dataclass(v):
            v = dataclass_to_dict(v)
        elif isinstance(v, (tuple, list)) and any(dataclasses.is_dataclass(x) for x in v):
            v = [dataclass_to_dict(x) for x in v]              # written as inline tables
        out[f.name] = v
    return out


# ----------------------------------------------------------------------------- dataclasses
def _dataclass_of(hint) -> type | None:
    """The dataclass type of a field annotation ``X`` or ``X | None``, else None."""
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        return hint
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        found = [a for a in typing.get_args(hint) if dataclasses.is_dataclass(a) and isinstance(a, type)]
        return found[0] if len(found) == 1 else None
    return None


def _convert(hint, value, where: str, key: str):
    """``value`` as the field's type; FileFormatError naming ``where`` and ``key`` if it is not one."""
    def bad(kind: str):
        return FileFormatError(f"{where}: {key} = {value!r} is not {kind}")

    base = hint
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        base = args[0] if len(args) == 1 else hint
    if base is bool:
        if not isinstance(value, bool):
            raise bad("a boolean (true/false)")
        return value
    if base is int:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value):
            raise bad("an integer")
        return int(value)
    if base is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise bad("a number")
        return float(value)
    if base is str:
        if not isinstance(value, str):
            raise bad("a string")
        return value
    if typing.get_origin(base) is tuple or base is tuple:
        if not isinstance(value, (list, tuple)):
            raise bad("a list")
        args = typing.get_args(base)
        if len(args) == 2 and args[1] is Ellipsis:          # tuple[X, ...]
            args = (args[0],) * len(value)
        elif args and len(args) != len(value):
            raise bad(f"a list of {len(args)}")
        if not args:
            return tuple(value)
        return tuple(_item(a, v, where, f"{key}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
    return value


def _item(hint, value, where: str, key: str):
    """One element of a tuple field: a settings dataclass from an inline table, else ``_convert``."""
    sub = _dataclass_of(hint)
    if sub is not None:
        return dataclass_from_dict(sub, value, f"{where} {key}")
    return _convert(hint, value, where, key)


def dataclass_from_dict(cls: type[T], table: dict, where: str, base: T | None = None) -> T:
    """An instance of the settings dataclass ``cls`` from a parsed TOML table.

    Keys are field names; a field that is a dataclass (or ``X | None``) takes a sub-table,
    whose keys replace those of the field's default (``base``: the instance whose values the
    table replaces; default ``cls()`` when every field has a default). Unknown keys, values
    of the wrong type and values ``cls`` rejects raise ``FileFormatError`` naming ``where``
    (the file and table) and the key.
    """
    if not isinstance(table, dict):
        raise FileFormatError(f"{where}: must be a table, got {table!r}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    unknown = [k for k in table if k not in names]
    if unknown:
        raise FileFormatError(f"{where}: unknown key(s) {sorted(unknown)} (known: {sorted(names)})")
    if base is None:
        try:
            base = cls()
        except TypeError:                  # a field without a default: the table must give it
            base = None
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        sub = _dataclass_of(hints[key])
        if sub is not None:
            if not isinstance(value, dict):
                raise FileFormatError(f"{where}: {key} must be a table [{key}]")
            default = getattr(base, key, None)
            kwargs[key] = dataclass_from_dict(sub, value, f"{where} [{key}]",
                                              default if isinstance(default, sub) else None)
        else:
            kwargs[key] = _convert(hints[key], value, where, key)
    try:
        return dataclasses.replace(base, **kwargs) if base is not None else cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise FileFormatError(f"{where}: {exc}") from None


@functools.cache
def _path_fields(cls: type) -> tuple[str, ...]:
    """The fields of the dataclass ``cls`` annotated ``Path`` or ``Path | None``."""
    hints = typing.get_type_hints(cls)
    return tuple(f.name for f in dataclasses.fields(cls)
                 if hints[f.name] is Path or (typing.get_origin(hints[f.name]) in (typing.Union, types.UnionType)
                                              and Path in typing.get_args(hints[f.name])))


def coerce_paths(obj) -> None:
    """Make every ``Path`` field of the (frozen) dataclass instance ``obj`` that holds a str a
    ``Path`` (for ``__post_init__``: a TOML file or a caller gives paths as strings)."""
    for name in _path_fields(type(obj)):
        value = getattr(obj, name)
        if isinstance(value, str):
            object.__setattr__(obj, name, Path(value))


def load_dataclass(cls: type[T], path: str | Path, table: str | None = None,
                   required: bool = False) -> T:
    """Read a settings dataclass ``cls`` from the TOML file ``path``.

    table : the file's table holding the fields (e.g. "perception"). When the file has
        it, nothing else may be beside it; when it has not, the file's top-level keys are
        the fields (an error with ``required``). None: the top-level keys are the fields.
    Errors (``FileFormatError``, ``FileNotFoundError``) name the file and the key.
    """
    doc = read_toml(path, f"{cls.__name__} settings file")
    where = str(path)
    if table is not None and table in doc:
        extra = [k for k in doc if k != table]
        if extra:
            raise FileFormatError(f"{where}: unknown key(s) {sorted(extra)} beside [{table}]")
        return dataclass_from_dict(cls, doc[table], f"{where} [{table}]")
    if table is not None and required:
        raise FileFormatError(f"{where}: missing [{table}] table")
    return dataclass_from_dict(cls, doc, where)

