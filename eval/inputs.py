"""The files a run reads, fingerprinted, so a results directory is never resumed with other ones.

A results directory's identity is its config (``eval.results_dir``), but a config names some of
its inputs only by path -- and the default ones not at all: ``segmenter.weights: ""`` means
``agent/weights/<model>.pt``, which a retraining replaces in place. Resuming a run after that
would mix maps, scans or episodes of two networks under one config. ``input_fingerprints(cfg)``
lists every file the config reads, with its sha256:

- the keys whose value always names something a loader reads (``FILE_KEYS``: segmenter
  ``weights``, ``model`` and ``label_map``, ``predictor_weights``, ``glfs_params``), whatever
  the value looks like: a file is hashed; a model directory (``hf``: a ``save_pretrained``
  folder) is hashed as the list of its files and their sha256 (a file added, removed or
  replaced changes it); a Hugging Face hub id (``org/name``) is hashed as its snapshot in the
  local Hugging Face cache when there is one; a built-in label map name (``ade20k``, ...) as
  its shipped ``.tsv``;
- every other string value of the resolved config that names an existing file (a value with
  a file suffix or a directory part, found from the working directory or, as the loaders also
  look, from the repository root), under its dotted key;
- the default weight files a config reads without naming them: each learned segmenter it runs
  (``agent.segmenter``, ``study.segmenters``) when the ``segmenter`` section's ``weights`` is
  empty, and the target predictor
  (``agent.exploration: prediction``) when ``agent.predictor_weights`` is empty.

- a habitat-lab episode dataset (``env.dataset.data_path``): every file of the split, by content,
  and every scene file its episodes name with the files of its scene beside it (semantic mesh,
  annotations) by path, size and modification time -- a scan is up to a gigabyte, and hashing a
  split's scans at every resume would take minutes.

Other directories (a recorded sequence, a scene folder) are not hashed. Hashes are cached per
process by the file's stat, so a multirun hashes each file once.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from calnav.common.weights import resolve_repo_path

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


# Keys (the last part of a dotted key) whose value always names an input the loaders read, so
# they are resolved whatever the value looks like (``pred`` without a suffix is still a file).
FILE_KEYS: tuple[str, ...] = ("weights", "model", "label_map", "predictor_weights", "glfs_params")
DIRECTORY_KEYS: tuple[str, ...] = ("model",)   # of those, the ones that may name a directory (hf)


@dataclass(frozen=True)
class StatFile:
    """A file fingerprinted by its path, size and modification time (a large scene file)."""

    path: Path


@dataclass(frozen=True)
class InputDir:
    """A model directory a loader reads as a whole (``hf``'s ``save_pretrained`` folder)."""

    path: Path


def _as_file(value: str) -> Path | None:
    """The existing file a config string names, resolved as the loaders do (working directory,
    then the repository root for a relative path), or None. Only strings that look like paths
    (a suffix or a directory part) are considered, so a value such as ``val`` never matches a
    stray file of that name."""
    if not Path(value).suffix and len(Path(value).parts) < 2:
        return None
    path = resolve_repo_path(value)
    return path if path.is_file() else None


def _hub_snapshot(model_id: str) -> Path | None:
    """The local Hugging Face cache's snapshot of hub id ``model_id`` (what ``from_pretrained``
    loads offline), or None when it is not cached or ``huggingface_hub`` is not installed."""
    if model_id.count("/") != 1 or model_id.startswith(("/", ".", "~")):
        return None
    try:
        from huggingface_hub import snapshot_download
    except ImportError:
        return None
    try:
        return Path(snapshot_download(model_id, local_files_only=True))
    except Exception:  # noqa: BLE001 -- not cached, or not a valid hub id: nothing calnav can name
        return None


def _named_input(key: str, value: str) -> Path | InputDir | None:
    """What a ``FILE_KEYS`` value names (module docstring), or None."""
    from calnav.agent.segmenters.label_map import BUILTIN_LABEL_MAPS, LABEL_MAP_DIR

    name = key.rsplit(".", 1)[-1]
    if name == "label_map" and value in BUILTIN_LABEL_MAPS:   # read_label_map: a built-in name wins
        return LABEL_MAP_DIR / f"{value}.tsv"
    path = resolve_repo_path(value)
    if path.is_file():
        return path
    if name in DIRECTORY_KEYS:
        if path.is_dir():
            return InputDir(path)
        snapshot = _hub_snapshot(value)
        return InputDir(snapshot) if snapshot is not None else None
    return None


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
                segmenters: tuple[str, ...] | None = None) -> dict[str, Path | InputDir]:
    """{label: file or model directory} the resolved config dict reads (module docstring);
    ``neutral_keys`` are skipped (output directories and the like); ``segmenters``: the
    segmenters the command runs when they are not the config's (``fit-glfs --segmenter``)."""
    from calnav.agent.prediction import DEFAULT_PREDICTOR
    from calnav.agent.segmenters.learned import LEARNED_MODELS, default_weights_path

    out: dict[str, Path | InputDir] = {}
    for key, value in _leaves(cfg_dict):
        if key in neutral_keys or not isinstance(value, str) or not value:
            continue
        found = _named_input(key, value) if key.rsplit(".", 1)[-1] in FILE_KEYS else _as_file(value)
        if found is not None:
            out[key] = found
    agent, study = cfg_dict.get("agent") or {}, cfg_dict.get("study") or {}
    seg = cfg_dict.get("segmenter") or {}   # the segmenter settings the run reads
    if not seg.get("weights"):
        names = list(segmenters) if segmenters is not None else \
            [agent.get("segmenter")] + list(study.get("segmenters") or [])
        for name in dict.fromkeys(n for n in names if n in LEARNED_MODELS):
            out[f"segmenter.weights ({name} default)"] = default_weights_path(name)
    if agent.get("exploration") == "prediction" and not agent.get("predictor_weights"):
        out["agent.predictor_weights (default)"] = DEFAULT_PREDICTOR
    out.update(_dataset_inputs(cfg_dict.get("env") or {}))
    return out


def _dataset_inputs(env: dict) -> dict[str, Path | StatFile]:
    """The files of the habitat-lab dataset ``env.dataset.data_path`` names (module docstring)."""
    dataset = env.get("dataset") or {}
    if not dataset.get("data_path"):
        return {}
    from calnav.envs.episode_datasets import read_dataset, resolve_scene_config
    from calnav.envs.file_episodes import scene_file_key

    split, data_path, scene_dir = env.get("split", "val"), dataset["data_path"], dataset.get("scene_dir", "")
    source = read_dataset(data_path, split)
    out: dict[str, Path | StatFile] = {f"env.dataset.data_path ({p.name})": p
                                       for p in dict.fromkeys((source.source.path, *source.source.files))}
    for scene_id in source.scene_ids():
        for path, _, _ in scene_file_key(scene_id, scene_dir):
            out[f"env.dataset.scene_dir ({Path(path).name})"] = StatFile(Path(path))
    for named in dict.fromkeys(ep.scene_dataset_config for ep in source.episodes):   # the configs episodes name
        config = resolve_scene_config(named, scene_dir)
        if config is not None:
            out[f"env.dataset.scene_dir ({config.name})"] = StatFile(config)
    return out


def _dir_files(root: Path) -> list[Path]:
    """The files of ``root`` a loader reads, sorted: its top-level regular files (symlinks
    followed, as the Hugging Face cache's snapshots are links; ``from_pretrained`` reads
    ``config.json``, the weights and the processor files there), hidden ones left out (a
    download's lock files). Subdirectories -- a trainer's ``checkpoint-*`` folders, TensorBoard
    ``runs/`` -- are not read by the loader and would make every resume look like another model."""
    return sorted(p for p in root.iterdir() if p.is_file() and not p.name.startswith("."))


def fingerprint(found: Path | InputDir) -> dict:
    """{"path", "sha256"} of a file; of a model directory also {"files": {relative path:
    sha256}}, its sha256 being that of the sorted list of (relative path, sha256) pairs."""
    if isinstance(found, Path):
        return {"path": str(found), "sha256": sha256_file(found)}
    if isinstance(found, StatFile):
        st = found.path.stat()
        key = f"{found.path.resolve()}\0{st.st_size}\0{st.st_mtime_ns}"
        return {"path": str(found.path), "sha256": hashlib.sha256(key.encode()).hexdigest(), "by": "path, size, mtime"}
    files = {str(p.relative_to(found.path)): sha256_file(p) for p in _dir_files(found.path)}
    listing = "".join(f"{rel}\0{sha}\n" for rel, sha in files.items())
    return {"path": str(found.path), "sha256": hashlib.sha256(listing.encode()).hexdigest(), "files": files}


def input_fingerprints(cfg_dict: dict, neutral_keys: tuple[str, ...] = (),
                       segmenters: tuple[str, ...] | None = None) -> dict[str, dict]:
    """{label: ``fingerprint``} of ``input_files`` (a missing default file is left out: the
    command itself reports it)."""
    return {key: fingerprint(found) for key, found in input_files(cfg_dict, neutral_keys, segmenters).items()
            if _present(found)}


def _present(found: Path | InputDir | StatFile) -> bool:
    return True if isinstance(found, InputDir) else (found.path if isinstance(found, StatFile) else found).is_file()


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
