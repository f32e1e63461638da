"""The files a run reads, fingerprinted, so a results directory is never resumed with other ones.

A results directory's identity is its config (``eval.results_dir``), but a config names some of
its inputs only by path -- and the default ones not at all: ``segmenter.weights: ""`` means
``agent/weights/<model>.pt``, which a retraining replaces in place. Resuming a run after that
would mix maps, scans or episodes of two networks under one config. ``input_fingerprints(cfg)``
lists every file the config reads, with its sha256:

- every string value of the resolved config that names an existing file (weights, GLFS
  parameters, label maps, ...: a value with a file suffix or a directory part, found from the
  working directory or, as the loaders also look, from the repository root), under its dotted key;
- the default weight files a config reads without naming them: each learned segmenter it runs
  (``agent.segmenter``, ``study.segmenters``) when its segmenter section's ``weights`` is empty
  (``agent.segmenter_config`` or the top-level ``segmenter``), and the target predictor
  (``agent.exploration: prediction``) when ``agent.predictor_weights`` is empty.

Directories (a recorded sequence, a Hugging Face model folder) are not hashed. Hashes are
cached per process by the file's stat, so a multirun hashes each file once.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Iterator

INPUTS_NAME = "inputs.json"
_CHUNK = 1 << 20


_HASHES: dict[tuple, str] = {}   # (path, mtime_ns, size, inode) -> sha256


def sha256_file(path: Path) -> str:
    """The file's sha256 (hex), from the per-process cache while its stat is unchanged."""
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size, st.st_ino)
    if key not in _HASHES:
        h = hashlib.sha256()
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(_CHUNK), b""):
                h.update(chunk)
        _HASHES[key] = h.hexdigest()
    return _HASHES[key]


def _as_file(value: str) -> Path | None:
    """The existing file a config string names, resolved as the loaders do (working directory,
    then the repository root for a relative path), or None. Only strings that look like paths
    (a suffix or a directory part) are considered, so a value such as ``val`` never matches a
    stray file of that name."""
    from calnav.common.weights import resolve_repo_path

    if not Path(value).suffix and len(Path(value).parts) < 2:
        return None
    path = resolve_repo_path(value)
    return path if path.is_file() else None


def _leaves(d: dict, prefix: str = "") -> Iterator[tuple[str, object]]:
    for key, value in d.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict):
            yield from _leaves(value, dotted + ".")
        elif isinstance(value, list):
            for i, item in enumerate(value):
                yield f"{dotted}[{i}]", item
        else:
            yield dotted, value


def input_files(cfg_dict: dict, neutral_keys: tuple[str, ...] = (),
                segmenters: tuple[str, ...] | None = None) -> dict[str, Path]:
    """{label: file} the resolved config dict reads (module docstring); ``neutral_keys`` are
    skipped (output directories and the like); ``segmenters``: the segmenters the command runs
    when they are not the config's (``fit-glfs --segmenter``)."""
    from calnav.agent.prediction import DEFAULT_PREDICTOR
    from calnav.agent.segmenters.learned import LEARNED_MODELS, default_weights_path

    out: dict[str, Path] = {}
    for key, value in _leaves(cfg_dict):
        if key in neutral_keys or not isinstance(value, str) or not value:
            continue
        path = _as_file(value)
        if path is not None:
            out[key] = path
    agent, study = cfg_dict.get("agent") or {}, cfg_dict.get("study") or {}
    seg = agent.get("segmenter_config") or cfg_dict.get("segmenter") or {}   # the section the run reads
    if not seg.get("weights"):
        names = list(segmenters) if segmenters is not None else \
            [agent.get("segmenter")] + list(study.get("segmenters") or [])
        for name in dict.fromkeys(n for n in names if n in LEARNED_MODELS):
            out[f"segmenter.weights ({name} default)"] = default_weights_path(name)
    if agent.get("exploration") == "prediction" and not agent.get("predictor_weights"):
        out["agent.predictor_weights (default)"] = DEFAULT_PREDICTOR
    return out


def input_fingerprints(cfg_dict: dict, neutral_keys: tuple[str, ...] = (),
                       segmenters: tuple[str, ...] | None = None) -> dict[str, dict[str, str]]:
    """{label: {"path": str, "sha256": hex}} of ``input_files`` (a missing default file is left
    out: the command itself reports it)."""
    return {key: {"path": str(path), "sha256": sha256_file(path)}
            for key, path in input_files(cfg_dict, neutral_keys, segmenters).items() if path.is_file()}


def changed_inputs(saved: dict, now: dict) -> list[str]:
    """Labels of the files both fingerprint dicts list whose content differs (a malformed saved
    entry counts as changed). A file only one side lists is not a change: the configs, compared
    separately, name the same files, so it is a default the other command did not read (a
    calibrate-map directory resumed by fit-glfs for one of its segmenters)."""
    def sha(d: dict, k: str):
        entry = d.get(k)
        return entry.get("sha256") if isinstance(entry, dict) else entry
    return sorted(k for k in set(saved) & set(now) if sha(saved, k) != sha(now, k))


def read_saved_inputs(path: Path) -> dict | None:
    """A results directory's saved fingerprints (``inputs.json``), None when it has none;
    ValueError (one line) when the file cannot be read as a JSON object."""
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path} is not readable JSON ({type(exc).__name__})") from None
    return data if isinstance(data, dict) else {}
