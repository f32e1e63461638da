"""Versioned ``.npz`` files: named arrays plus one JSON metadata record (the ``meta`` entry)
whose ``format_version`` says which layout the file has.

``save_versioned_npz`` writes atomically (``common.atomic``: a crash never leaves a
half-written file); ``load_versioned_npz`` returns (arrays, meta) and raises
``error`` (default ``NpzFormatError``, a ValueError) naming the file when it is missing, is not
a readable ``.npz`` with a JSON ``meta`` record, lacks a format version or has another one.
``check_format_version`` is that last check alone, for metadata read some other way (e.g. JSON).
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Mapping

import numpy as np

from calnav.common.atomic import atomic_path

META_KEY = "meta"
VERSION_KEY = "format_version"


class NpzFormatError(ValueError):
    """A versioned file is missing, unreadable or has another format version."""


def check_format_version(meta: Mapping, version: int, path: str | os.PathLike, what: str = "file",
                         error: type[Exception] = NpzFormatError) -> None:
    """Raise ``error`` naming ``path`` unless ``meta["format_version"] == version``."""
    if VERSION_KEY not in meta:
        raise error(f"{what} {path} has no {VERSION_KEY} in its metadata, expected format {version}")
    if meta[VERSION_KEY] != version:
        raise error(f"{what} {path} has format {meta[VERSION_KEY]}, expected {version}")


def save_versioned_npz(path: str | os.PathLike, arrays: Mapping[str, np.ndarray], meta: Mapping,
                       version: int) -> Path:
    """Write ``arrays`` and the JSON record ``{"format_version": version, **meta}`` to the
    compressed ``.npz`` ``path`` (parent folders created), atomically. Returns the path."""
    if META_KEY in arrays:
        raise ValueError(f"array name {META_KEY!r} is reserved for the metadata record")
    if VERSION_KEY in meta:
        raise ValueError(f"meta must not carry {VERSION_KEY!r}: pass the version as version=")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {VERSION_KEY: version, **meta}
    with atomic_path(path) as tmp:  # a crash never leaves a half-written file
        np.savez_compressed(tmp, **arrays, **{META_KEY: np.array(json.dumps(record))})
    return path


def load_versioned_npz(path: str | os.PathLike, version: int, what: str = "file",
                       error: type[Exception] = NpzFormatError) -> tuple[dict[str, np.ndarray], dict]:
    """(arrays without ``meta``, meta dict) of the ``.npz`` ``path``, written by
    ``save_versioned_npz`` with format ``version``. ``what`` names the kind of file in error
    messages (e.g. "scene file"); ``error`` is the exception class raised."""
    path = Path(path)
    if not path.exists():
        raise error(f"{what} not found: {path}")
    try:
        data = np.load(path, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise ValueError("a single .npy array, not a .npz archive")
        with data:
            arrays = {k: data[k] for k in data.files}
        if META_KEY not in arrays:
            raise ValueError(f"no {META_KEY!r} record")
        meta = json.loads(str(arrays.pop(META_KEY)))
        if not isinstance(meta, dict):
            raise ValueError(f"the {META_KEY!r} record is not a JSON object")
    except Exception as exc:  # zip / npz / json errors all mean the same thing to the user
        raise error(f"corrupt {what} {path}: {exc}") from exc
    check_format_version(meta, version, path, what, error)
    return arrays, meta
