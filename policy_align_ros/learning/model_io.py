"""Model files: one ``.npz`` of numeric arrays plus a JSON header (``docs/design.md`` section 4).

The header is stored as a 0-d unicode array named ``__header__`` so that the file loads
with ``allow_pickle=False``. Files are written to a temporary file in the target directory,
flushed to disk and renamed over the target, so a reader never sees half a model.
"""

from __future__ import annotations

import json
import math
import os
import uuid
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "FORMAT_VERSION",
    "save_npz",
    "load_npz",
    "load_header",
    "atomic_write_bytes",
    "atomic_write_text",
    "json_float",
    "json_floats",
    "to_json",
]

FORMAT_VERSION = 1
_HEADER = "__header__"


def atomic_write_bytes(path: str | Path, writer) -> Path:
    """Call ``writer(file_object)`` on a temporary file, fsync it and rename it to ``path``.

    The file's mode follows the process umask (``0o666 & ~umask``), as for ``open``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".{path.name}.{uuid.uuid4().hex[:12]}.tmp"
    # Not mkstemp: its 0600 would survive the rename. Created with 0666 the file gets what
    # the umask allows (0644 under 022), like any file a program writes; O_EXCL keeps the
    # name exclusive as mkstemp would.
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0),
                 0o666)
    try:
        with os.fdopen(fd, "wb") as fh:
            writer(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically, like :func:`atomic_write_bytes`."""
    return atomic_write_bytes(path, lambda fh: fh.write(text.encode("utf-8")))


def to_json(value: Any, field: str) -> Any:
    """``value`` with NumPy scalars made plain Python numbers, for a JSON header.

    Parameters
    ----------
    value : object
        ``None``, a bool, int, float or str, a NumPy scalar of such a type, or a dict
        (string keys), list or tuple of these (converted recursively; tuples become lists).
    field : str
        Name of the value in the header, for the error message (nested items add
        ``.key`` or ``[index]``).

    Returns
    -------
    object
        The same value built from plain Python types only; ``value`` is not modified.

    Raises
    ------
    ValueError
        Naming the (nested) field and its type when something cannot be written as JSON
        (an array, a generator object, a dict with a non-string key, ...).
    """
    if value is None or type(value) in (bool, int, float, str):
        return value
    if isinstance(value, (bool, int, float, str, np.generic)):  # np.float64, IntEnum, ...
        return _plain(value, field)
    if isinstance(value, dict):
        out = {}
        for key, item in value.items():
            if not isinstance(key, str):
                raise ValueError(f"header field {field!r}: key {key!r} is not a string, "
                                 "which JSON cannot hold")
            out[key] = to_json(item, f"{field}.{key}")
        return out
    if isinstance(value, (list, tuple)):
        return [to_json(item, f"{field}[{i}]") for i, item in enumerate(value)]
    raise ValueError(f"header field {field!r}: a {type(value).__name__} cannot be written "
                     "as JSON (give a number, string, bool, None, list or dict)")


def json_float(value: Any, nonfinite: str = "keep") -> Any:
    """A float or NumPy scalar as the plain Python value a JSON document holds.

    Parameters
    ----------
    value : float, int, bool, NumPy scalar or None
        ``None`` is returned as is.
    nonfinite : {"keep", "string", "null"}
        What a NaN or infinite float becomes: kept as a float (``json`` writes ``NaN`` and
        ``Infinity``), the string ``"nan"``, ``"inf"`` or ``"-inf"`` (model headers, which
        ``float()`` reads back), or ``None``.

    Returns
    -------
    float, int, bool, str or None

    Raises
    ------
    TypeError
        ``value`` is not a number (so that it serves as ``json.dumps(default=...)``).
    """
    if value is None:
        return None
    if isinstance(value, np.generic) and isinstance(value.item(), (bool, int, float)):
        value = value.item()
    if not isinstance(value, (bool, int, float)):
        raise TypeError(f"not JSON-serialisable: {type(value)}")
    if isinstance(value, float) and not math.isfinite(value):
        if nonfinite == "string":
            return "nan" if math.isnan(value) else "inf" if value > 0 else "-inf"
        if nonfinite == "null":
            return None
        if nonfinite != "keep":
            raise ValueError(f"nonfinite must be 'keep', 'string' or 'null', got {nonfinite!r}")
    return value


def json_floats(value: Any) -> Any:
    """``value`` with every float, in nested dicts too, as :func:`json_float` with
    ``nonfinite="null"`` makes it: a non-finite one as None (for reports that are JSON).

    Other values (lists included) are returned as they are.
    """
    if isinstance(value, dict):
        return {key: json_floats(v) for key, v in value.items()}
    if isinstance(value, float):
        return json_float(value, "null")
    return value


def _plain(value: Any, field: str) -> bool | int | float | str:
    """A scalar of a subclass of bool, int, float or str, or a NumPy scalar, as the
    plain Python value."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    if isinstance(value, (str, np.str_)):
        return str(value)
    raise ValueError(f"header field {field!r}: a {type(value).__name__} cannot be written "
                     "as JSON (give a number, string, bool, None, list or dict)")


def save_npz(path: str | Path, header: dict, arrays: dict[str, np.ndarray]) -> Path:
    """Write ``arrays`` and a JSON ``header`` atomically; returns the path written.

    NumPy scalars in ``header`` are written as plain numbers (:func:`to_json`); anything
    else JSON cannot hold raises a ValueError naming the field, before anything is written.
    """
    header = to_json({"format_version": FORMAT_VERSION, **header}, "header")
    payload = {_HEADER: np.array(json.dumps(header))}
    for name, value in arrays.items():
        value = np.asarray(value)
        if value.dtype == object:
            raise ValueError(f"array {name!r} has dtype object, which would need pickle")
        payload[name] = value
    return atomic_write_bytes(path, lambda fh: np.savez(fh, **payload))


def load_header(path: str | Path, kind: str) -> dict:
    """The JSON header of a file written by ``save_npz``, without reading its arrays.

    Raises as :func:`load_npz`.
    """
    return load_npz(path, kind, with_arrays=False)[0]


def load_npz(path: str | Path, kind: str, *, with_arrays: bool = True
             ) -> tuple[dict, dict[str, np.ndarray]]:
    """Read a file written by ``save_npz``; errors name the file and the problem.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        The file is truncated, not a model file, of another kind, of a newer format, or
        its header is not a JSON object or has no integer ``format_version``.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: model file not found")
    if not zipfile.is_zipfile(path):
        # np.load would take any other bytes for a pickle and say so, which misleads.
        raise ValueError(f"{path}: truncated or not a model file (not an .npz archive)")
    try:
        with np.load(path, allow_pickle=False) as data:
            if _HEADER not in data.files:
                raise ValueError("no header: not a policy_align_ros model file")
            header = json.loads(str(data[_HEADER]))
            arrays = {name: data[name] for name in data.files
                      if name != _HEADER} if with_arrays else {}
    except (zipfile.BadZipFile, OSError, EOFError, json.JSONDecodeError) as err:
        raise ValueError(f"{path}: truncated or not a model file ({err})") from None
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
    if not isinstance(header, dict):
        raise ValueError(f"{path}: malformed model file (the header is a JSON "
                         f"{type(header).__name__}, not an object)")
    version = header.get("format_version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise ValueError(f"{path}: malformed model file (format_version must be a positive "
                         f"integer, got {version!r})")
    if version > FORMAT_VERSION:
        raise ValueError(
            f"{path}: model format version {version!r} is newer than this package "
            f"supports ({FORMAT_VERSION}); upgrade policy_align_ros"
        )
    if header.get("kind") != kind:
        raise ValueError(f"{path}: holds a {header.get('kind')!r} model, expected {kind!r}")
    return header, arrays
