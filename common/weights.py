"""Versioned torch weight files: a plain dict saved with ``torch.save``, loaded with
``weights_only=True`` and a ``format`` number, with errors that name the file and how to make it;
and the lookup of shipped files that configs name relative to the repository root."""
from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]


def resolve_repo_path(path: str | os.PathLike) -> Path:
    """``path`` as given, or, when it is relative and missing from the working directory, the
    same path under the repository root if it exists there (how configs name shipped files such
    as ``agent/weights/glfs_learned_rgb.json``; ``eval.inputs`` fingerprints by the same rule)."""
    path = Path(path)
    if not path.exists() and not path.is_absolute() and (REPO_ROOT / path).exists():
        return REPO_ROOT / path
    return path


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
    check_finite_tensors(data.get("state_dict"), path, what, create)
    return data


def check_finite_tensors(state_dict, path: Path | str, what: str, create: str) -> None:
    """ValueError naming ``path`` and the first tensor of ``state_dict`` ({name: tensor}) that
    holds NaN or inf: such weights load and run, but every output they feed is NaN, which the
    consumers would otherwise treat as "no information" (a NaN predictor silently turns the
    prediction agent into the frontier agent)."""
    import torch

    if not isinstance(state_dict, dict):
        return   # not a tensor dict: the loader's own shape check names the damage
    for name, tensor in state_dict.items():
        if isinstance(tensor, torch.Tensor) and tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise ValueError(f"{what} weights {path} hold NaN or inf (tensor {name!r}); create them again with: "
                             f"{create}")
