"""The files a run reads, fingerprinted, so a results directory is never resumed with other ones.

A results directory's identity is its config (``eval.results_dir``), but a config names some of
its inputs only by path -- and the default ones not at all: ``segmenter.weights: ""`` means
``agent/weights/<model>.pt``, which a retraining replaces in place. Resuming a run after that
would mix maps, scans or episodes of two networks under one config. ``input_fingerprints(cfg)``
lists every file the config reads, with its sha256:

- every string value of the resolved config that names an existing file (weights, GLFS
  parameters, label maps, ...), under its dotted key;
- the default weight files a config reads without naming them: each learned segmenter it runs
  (``agent.segmenter``, ``study.segmenters``) when ``segmenter.weights`` is empty, and the target
  predictor (``agent.exploration: prediction``) when ``agent.predictor_weights`` is empty.

Directories (a recorded sequence, a Hugging Face model folder) are not hashed.
"""
from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Iterator

INPUTS_NAME = "inputs.json"
_CHUNK = 1 << 20


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(_CHUNK), b""):
            h.update(chunk)
    return h.hexdigest()


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


def input_files(cfg_dict: dict, neutral_keys: tuple[str, ...] = ()) -> dict[str, Path]:
    """{label: file} the resolved config dict reads (module docstring); ``neutral_keys`` are
    skipped (output directories and the like)."""
    from calnav.agent.prediction import DEFAULT_PREDICTOR
    from calnav.agent.segmenters.learned import LEARNED_MODELS, default_weights_path

    out: dict[str, Path] = {}
    for key, value in _leaves(cfg_dict):
        if key in neutral_keys or not isinstance(value, str) or not value:
            continue
        path = Path(value)
        if path.is_file():
            out[key] = path
    agent, study, seg = cfg_dict.get("agent") or {}, cfg_dict.get("study") or {}, cfg_dict.get("segmenter") or {}
    if not seg.get("weights"):
        names = [agent.get("segmenter")] + list(study.get("segmenters") or [])
        for name in dict.fromkeys(n for n in names if n in LEARNED_MODELS):
            out[f"segmenter.weights ({name} default)"] = default_weights_path(name)
    if agent.get("exploration") == "prediction" and not agent.get("predictor_weights"):
        out["agent.predictor_weights (default)"] = DEFAULT_PREDICTOR
    return out


def input_fingerprints(cfg_dict: dict, neutral_keys: tuple[str, ...] = ()) -> dict[str, dict[str, str]]:
    """{label: {"path": str, "sha256": hex}} of ``input_files`` (a missing default file is left
    out: the command itself reports it)."""
    return {key: {"path": str(path), "sha256": sha256_file(path)}
            for key, path in input_files(cfg_dict, neutral_keys).items() if path.is_file()}


def changed_inputs(saved: dict, now: dict) -> list[str]:
    """Labels whose file differs between two fingerprint dicts (added, removed or other content)."""
    return sorted(k for k in set(saved) | set(now)
                  if (saved.get(k) or {}).get("sha256") != (now.get(k) or {}).get("sha256"))
