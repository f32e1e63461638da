"""Atomic file writes: readers (and a rerun after a crash) see the old file or the new one, never
half of one.

Every write goes to a unique temporary file in the target's own directory (so ``os.replace``
stays on one file system and is atomic), is fsynced, then renamed over the target; the
directory is fsynced too so the rename survives a power cut. The temporary name is unique per
process and call (``.<stem>.<pid>-<hex>.tmp<suffix>``), so concurrent writers of one target
never share a temporary file, and it keeps the target's suffix, because some writers
(``np.savez``) append one when it is missing.

- ``write_bytes_atomic`` / ``write_text_atomic`` / ``write_json_atomic``: whole contents at once.
- ``json_text``: the one way calnav turns an object into JSON text: strict JSON (RFC 8259), so
  a NaN or an infinity is a ValueError naming where it is, never the bare ``NaN`` /
  ``Infinity`` that ``json.dumps`` writes by default and other JSON readers reject (a value
  that may be undefined is written as ``null`` by the code that knows it may be).
- ``undefined_as_null``: NaN as ``null``, for the writers whose NaN means "no data" (metrics
  of trainers and evaluations).
- ``atomic_path``: a context manager yielding the temporary path, for writers that need a path
  (``np.savez_compressed``, ``torch.save``, ``gzip.open``); the rename happens only when the
  block finishes without an exception, and the temporary file is removed otherwise.
- ``is_temp_file``: whether a name is such a temporary file (to skip in directory listings).
"""
from __future__ import annotations

import json
import math
import os
import re
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

TEMP_MARK = ".tmp"
_TEMP_NAME = re.compile(r"^\..+\.\d+-[0-9a-f]{8}" + re.escape(TEMP_MARK) + r"(\.[^.]*)?$")
UNIQUE_HEX_CHARS = 8  # random part of a temporary name (with the pid: unique per call)


def temp_path(path: str | os.PathLike) -> Path:
    """A fresh temporary sibling of ``path`` with the same suffix, e.g. ``a.npz`` ->
    ``.a.1234-0badc0de.tmp.npz``."""
    path = Path(path)
    token = f"{os.getpid()}-{uuid.uuid4().hex[:UNIQUE_HEX_CHARS]}"
    return path.with_name(f".{path.stem}.{token}{TEMP_MARK}{path.suffix}")


def is_temp_file(path: str | os.PathLike) -> bool:
    """True for a name made by ``temp_path`` (a write in progress, or left by a killed one)."""
    return bool(_TEMP_NAME.match(Path(path).name))


def _fsync_path(path: Path, directory: bool = False) -> None:
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path to write ``path``'s new contents to; on a clean exit it is fsynced
    and renamed over ``path`` (parent folders are created first). On an exception the
    temporary file is removed and ``path`` is left as it was."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path(path)
    try:
        yield tmp
        _fsync_path(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    try:
        _fsync_path(path.parent, directory=True)
    except OSError:  # some file systems cannot fsync a directory; the rename itself is done
        pass


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Replace ``path``'s contents with ``data`` atomically. Returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text_atomic(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Replace ``path``'s contents with ``text`` atomically. Returns the path."""
    return write_bytes_atomic(path, text.encode(encoding))


def _non_finite(obj, where: str = "") -> tuple[str, float] | None:
    """(place, value) of the first NaN / infinite float in ``obj``'s dicts and lists, or None."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return where or "the value", obj
    if isinstance(obj, dict):
        items = ((f"{where}.{k}" if where else str(k), v) for k, v in obj.items())
    elif isinstance(obj, (list, tuple)):
        items = ((f"{where}[{i}]", v) for i, v in enumerate(obj))
    else:
        return None
    for place, value in items:
        found = _non_finite(value, place)
        if found is not None:
            return found
    return None


def json_text(obj, indent: int | None = 2, what: str = "") -> str:
    """``obj`` as strict JSON text (``allow_nan=False``). ValueError in one line naming the
    first non-finite value's place (``what``: the file or record it is for) otherwise."""
    try:
        return json.dumps(obj, indent=indent, allow_nan=False)
    except ValueError:
        found = _non_finite(obj)
        if found is None:
            raise
        place, value = found
        raise ValueError(f"{what + ': ' if what else ''}{place} is {value}, which JSON cannot hold; "
                         "a non-finite number must not reach a JSON file") from None


def undefined_as_null(obj):
    """``obj`` with every NaN float -- a figure undefined for lack of data (an IoU of a class no
    pixel shows, an AUC without positives) -- as None (JSON ``null``), through dicts, lists and
    tuples. Only for writers whose NaN means "undefined": an infinity stays, and ``json_text``
    refuses it."""
    if isinstance(obj, float) and math.isnan(obj):
        return None
    if isinstance(obj, dict):
        return {k: undefined_as_null(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [undefined_as_null(v) for v in obj]
    return obj


def write_json_atomic(path: str | os.PathLike, obj, indent: int | None = 2) -> Path:
    """Write ``obj`` as strict JSON (``json_text``, with a final newline) to ``path``
    atomically; ValueError naming the file and the place of a non-finite value, before anything
    is written. Returns the path."""
    return write_text_atomic(path, json_text(obj, indent, what=str(path)) + "\n")
