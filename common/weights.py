"""Versioned torch weight files: a plain dict saved with ``torch.save``, loaded with
``weights_only=True`` and a ``format`` number, with errors that name the file and how to make it."""
from __future__ import annotations

from pathlib import Path


def load_weight_dict(path: Path | str, what: str, fmt: int, create: str) -> dict:
    """The dict in ``path``. ``what`` names the kind in messages ("segmenter", "predictor"),
    ``fmt`` is the expected ``format``, ``create`` the command that makes such a file.
    FileNotFoundError (naming ``create``) / ValueError (unreadable, not such a file)."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} weights not found: {path}; create them with: {create}")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 -- torch raises many types for a corrupt file
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ValueError(f"cannot read {what} weights {path}: {first}") from None
    if not isinstance(data, dict) or data.get("format") != fmt:
        raise ValueError(f"{path} is not a calnav {what} weight file (format {fmt})")
    return data
