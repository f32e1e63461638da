"""The scene library: which scenes make up each split, their seeds, and loading them (cached).

Procedural scenes (``DatasetConfig.scene_dir == ""``)
    Ids are ``house_<split>_<index:04d>`` (e.g. ``house_val_0003``), ``index`` in
    ``[0, <split>_scenes)``. A house's seed is

        scene_seed = BASE_SEED_STRIDE * base_seed + SPLIT_BLOCK * rank(split) + index

    with rank calib = 0, train = 1, val = 2, test = 3 (``calib``: the houses of the
    map-calibration study, which must be seen neither by segmenter training nor by ObjectNav
    episodes), ``SPLIT_BLOCK`` = 1,000,000 and
    ``BASE_SEED_STRIDE`` = 4,000,000: the splits draw from disjoint seed ranges, and so do
    different ``DatasetConfig.seed`` values (base seeds >= 0). Generated houses are cached at
    ``cache_dir()/scenes/<id>_<key>.npz``, ``key`` a hash of the seed, the ``HouseSpec`` and
    the generator version, so a changed spec or base seed gets a fresh file.

User scenes (``DatasetConfig.scene_dir`` set)
    Ids are the file stems of the ``*.npz`` (``Scene.save`` files) and ``*.ply`` (labelled
    meshes, see ``envs.scan``) in that directory, and the ids of the HM3D / MP3D scenes
    (``*.glb``) anywhere below it (``envs.scene_files.scene_files_in``); a stem present as both
    ``.npz`` and ``.ply`` loads the ``.npz``. Without ``train/``, ``val/``, ``test/`` subfolders
    every split lists the same (sorted) scenes; with them (an HM3D tree has ``train/`` and
    ``val/``), each split lists its own subfolder. A PLY's labels come from a sibling
    ``<stem>.labels.json`` or else ``labels.json``: either a plain ``{raw id: class name}``
    mapping or ``{"label_map": {...}, "up_axis": "y", "label_property": "label"}``; with
    neither, raw labels must already be calnav class ids. Files load through
    ``envs.scene_files.load_scene_file``; converted PLYs and GLBs are cached too.

Episode-file scenes (``DatasetConfig.data_path`` set as well)
    Ids are the ``scene_id`` paths of a habitat-lab episode file, resolved under ``scene_dir``
    as habitat-lab resolves them (``envs.episode_datasets.resolve_scene``).

Scanned houses (``DatasetConfig.style == "scanned"``)
    The same ids and seeds; the scene is the procedural house scanned and reconstructed by
    ``envs.scanning`` (seeded by the house seed), cached at
    ``cache_dir()/scenes/<id>_scan_<key>.npz``, ``key`` a hash of the house key, the
    ``ScanningConfig`` and ``SCANNER_VERSION``. User scenes are scans already: the style is
    refused with a ``scene_dir``.

Every cache file carries its identity in its metadata and is checked on load, like the parsed
episode sidecar (``envs.episode_files``): a generated house its ``scene_id``, ``seed`` and
``spec_digest`` (``procedural_identity``); a scan also its ``scan_seed``, ``scanner_version``
and ``scanning`` settings (``scanned_identity``); a converted PLY the file and stat key it was
converted from (``converted_from``, a GLB scene also its semantic files, configs and label map). A cache file that is damaged, or holds another scene (a
file copied over another, another house's scan), is a cache and nothing else: it is rebuilt,
with a warning naming the file and what it held.

Loaded scenes are kept in a small in-process LRU (``LRU_SIZE``); treat them as read-only.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import re
from collections import OrderedDict
from pathlib import Path

from calnav.envs.config import DatasetConfig
from calnav.envs.house import HouseSpec, generate_house
from calnav.envs.scene import Scene, cache_dir
from calnav.envs.scene_files import cached_scene, load_scene_file, save_atomic, scene_file_inputs, scene_files_in
from calnav.envs.stairs import StairSpec

SPLITS = ("train", "val", "test", "calib")
STYLES = ("clean", "scanned")               # DatasetConfig.style choices (envs.config.StyleName)
SPLIT_RANK = {"calib": 0, "train": 1, "val": 2, "test": 3}  # seed block of each split
SPLIT_BLOCK = 1_000_000                     # seeds per split block (max scenes per split)
BASE_SEED_STRIDE = 4 * SPLIT_BLOCK          # seed distance between consecutive base seeds
LRU_SIZE = 4                                # scenes kept in memory
USER_SEED_MODULUS = 2 ** 31                 # user-scene generation seeds lie in [0, this)
_ID_RE = re.compile(r"^house_(train|val|test|calib)_(\d+)$")
_lru: OrderedDict[tuple, Scene] = OrderedDict()


def _check_split(split: str) -> None:
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; valid splits: {', '.join(SPLITS)}")


def procedural_scene_id(split: str, index: int) -> str:
    """``house_<split>_<index:04d>``."""
    _check_split(split)
    if not 0 <= int(index) < SPLIT_BLOCK:
        raise ValueError(f"scene index must be in [0, {SPLIT_BLOCK}), got {index}")
    return f"house_{split}_{int(index):04d}"


def parse_scene_id(scene_id: str) -> tuple[str, int]:
    """(split, index) of a procedural id; ValueError naming the id format otherwise."""
    m = _ID_RE.match(str(scene_id))
    if not m or int(m.group(2)) >= SPLIT_BLOCK:
        raise ValueError(f"unknown scene id {scene_id!r}; procedural ids look like 'house_<split>_<NNNN>' "
                         f"with split one of {', '.join(SPLITS)} (e.g. 'house_val_0003')")
    return m.group(1), int(m.group(2))


def scene_seed(scene_id: str, base_seed: int = 0) -> int:
    """The ``generate_house`` seed of a procedural id (see the module docstring)."""
    split, index = parse_scene_id(scene_id)
    if base_seed < 0:
        raise ValueError(f"base seed must be >= 0, got {base_seed}")
    return BASE_SEED_STRIDE * int(base_seed) + SPLIT_BLOCK * SPLIT_RANK[split] + index


def generation_seed(scene_id: str, base_seed: int = 0) -> int:
    """The seed of the episodes generated in ``scene_id``: its house seed for a procedural id
    (``scene_seed``); for a user scene (any file name) a stable hash of the id and the base
    seed, in [0, 2^31)."""
    if _ID_RE.match(str(scene_id)):
        return scene_seed(scene_id, base_seed)
    if base_seed < 0:
        raise ValueError(f"base seed must be >= 0, got {base_seed}")
    digest = hashlib.sha1(f"{int(base_seed)}:{scene_id}".encode()).digest()
    return int.from_bytes(digest[:4], "little") % USER_SEED_MODULUS


# ------------------------------------------------------------------------- user scenes
def _split_dirs(root: Path) -> dict[str, Path] | None:
    """{split: folder} when ``root`` has split subfolders, else None (one shared list)."""
    found = {s: root / s for s in SPLITS if (root / s).is_dir()}
    return found or None


def _found(files: dict[str, Path], folder: Path) -> dict[str, Path]:
    """``files``, or ValueError when ``folder`` held none (a run would have nothing to do)."""
    if not files:
        raise ValueError(f"no scenes found in {folder}: put *.ply labelled meshes or *.npz calnav scenes there "
                         "(any file name), or HM3D / MP3D scene folders (*.glb) below it, and set env.dataset.scene_dir "
                         "to it")
    return files


def _user_files(scene_dir: str, split: str | None) -> dict[str, Path]:
    root = Path(scene_dir).expanduser()
    if not root.is_dir():
        raise ValueError(f"dataset.scene_dir {str(root)!r} is not a directory")
    dirs = _split_dirs(root)
    if dirs is None:
        return _found(scene_files_in(root), root)
    if split is not None:
        if split not in dirs:
            raise ValueError(f"{root} has split folders {sorted(dirs)} but no {split!r} folder")
        return _found(scene_files_in(dirs[split]), dirs[split])
    merged: dict[str, Path] = {}
    for folder in (dirs[s] for s in SPLITS if s in dirs):   # any split's scene loads by id; first split wins
        for stem, p in scene_files_in(folder).items():
            merged.setdefault(stem, p)
    return _found(merged, root)


# --------------------------------------------------------------------------------- api
def split_scene_ids(split: str, dataset_cfg: DatasetConfig | None = None) -> list[str]:
    """The scene ids of ``split`` ("train" | "val" | "test" | "calib") under ``dataset_cfg``."""
    _check_split(split)
    cfg = dataset_cfg or DatasetConfig()
    if cfg.scene_dir:
        return sorted(_user_files(cfg.scene_dir, split))
    count = int(getattr(cfg, f"{split}_scenes"))
    if not 0 <= count <= SPLIT_BLOCK:
        raise ValueError(f"dataset.{split}_scenes must be in [0, {SPLIT_BLOCK}], got {count}")
    return [procedural_scene_id(split, i) for i in range(count)]


def scene_cache_path(scene_id: str, dataset_cfg: DatasetConfig | None = None, spec: HouseSpec | None = None) -> Path:
    """Where the procedural scene ``scene_id`` is (or will be) cached."""
    cfg, spec = dataset_cfg or DatasetConfig(), spec or HouseSpec()
    seed = scene_seed(scene_id, cfg.seed)
    text = f"{spec.digest()}:{seed}"
    if cfg.storeys > 1:   # (a single-storey house keeps the key it had before storeys existed)
        text += ":" + json.dumps({"storeys": cfg.storeys, "stairs": StairSpec().digest_items()}, sort_keys=True)
    key = hashlib.sha1(text.encode()).hexdigest()[:12]
    return cache_dir() / "scenes" / f"{scene_id}_{key}.npz"


def scanned_cache_path(scene_id: str, dataset_cfg: DatasetConfig | None = None,
                       spec: HouseSpec | None = None) -> Path:
    """Where the scanned version of the procedural scene ``scene_id`` is (or will be) cached."""
    from calnav.envs.scanning.config import SCANNER_VERSION

    cfg = dataset_cfg or DatasetConfig()
    clean = scene_cache_path(scene_id, cfg, spec)
    scan = json.dumps([SCANNER_VERSION, cfg.scanning.digest_items()], sort_keys=True, default=list)
    key = hashlib.sha1(f"{clean.stem}:{scan}".encode()).hexdigest()[:12]
    return cache_dir() / "scenes" / f"{scene_id}_scan_{key}.npz"


def load_scene(scene_id: str, dataset_cfg: DatasetConfig | None = None, spec: HouseSpec | None = None,
               style: str | None = None, dataset_config: str = "") -> Scene:
    """The scene ``scene_id``: a procedural house (generated once, then read from the cache; with
    ``dataset_cfg.style == "scanned"`` its scan, see the module docstring) or, when
    ``dataset_cfg.scene_dir`` is set, a user scene file. ``style`` ("clean" | "scanned")
    overrides ``dataset_cfg.style``. dataset_config: the scene dataset config an episode file's
    episode names (``envs.episode_datasets.resolve_scene_config``). ValueError names the valid
    ids and styles."""
    cfg, spec = dataset_cfg or DatasetConfig(), spec or HouseSpec()
    if style is not None:
        if style not in STYLES:
            raise ValueError(f"unknown scene style {style!r}; valid styles: {', '.join(STYLES)}")
        cfg = dataclasses.replace(cfg, style=style)   # its checks refuse a scanned user scene_dir
    if cfg.scene_dir and cfg.data_path:   # an episode file's scene id: a path under scene_dir
        from calnav.envs.episode_datasets import resolve_scene, resolve_scene_config

        path, root = resolve_scene(scene_id, cfg.scene_dir), Path(cfg.scene_dir).expanduser()
        config = resolve_scene_config(dataset_config, cfg.scene_dir)
        key = ("file", json.dumps(scene_file_inputs(path, root, config)))
        loader = lambda: load_scene_file(path, root=root, dataset_config=config)  # noqa: E731
    elif cfg.scene_dir:
        files = _user_files(cfg.scene_dir, None)
        if scene_id not in files:
            shown = sorted(files)[:20]
            raise ValueError(f"unknown scene id {scene_id!r} in {cfg.scene_dir}; valid ids: "
                             f"{', '.join(shown) or '(none: no *.npz / *.ply files)'}{' ...' if len(files) > 20 else ''}")
        root = Path(cfg.scene_dir).expanduser()
        key = ("user", json.dumps(scene_file_inputs(files[scene_id], root)))
        loader = lambda: load_scene_file(files[scene_id], root=root)  # noqa: E731
    else:
        split, index = parse_scene_id(scene_id)
        count = int(getattr(cfg, f"{split}_scenes"))
        if index >= count:
            raise ValueError(f"scene id {scene_id!r} is outside the {split} split; valid ids: "
                             f"{procedural_scene_id(split, 0)} .. {procedural_scene_id(split, max(count - 1, 0))} "
                             f"(dataset.{split}_scenes = {count})")
        seed = scene_seed(scene_id, cfg.seed)
        clean_path = scene_cache_path(scene_id, cfg, spec)
        key = ("house", str(clean_path))
        loader = lambda: _load_procedural(scene_id, clean_path, seed, spec, cfg.storeys)  # noqa: E731
        if cfg.style == "scanned":
            clean_loader, scan_path = loader, scanned_cache_path(scene_id, cfg, spec)
            key = ("scanned", str(scan_path))
            identity = scanned_identity(scene_id, seed, spec, cfg)
            loader = lambda: _load_scanned(scan_path, clean_loader, identity, seed, cfg)  # noqa: E731
    if key in _lru:
        _lru.move_to_end(key)
        return _lru[key]
    scene = loader()
    _lru[key] = scene
    while len(_lru) > LRU_SIZE:
        _lru.popitem(last=False)
    return scene


def procedural_identity(scene_id: str, seed: int, spec: HouseSpec, storeys: int = 1) -> dict:
    """The metadata that makes a generated house's cache file this house's (``generate_house``
    writes ``seed``, ``spec_digest`` and, above one storey, ``storeys``; ``_load_procedural``
    the ``scene_id``)."""
    out = {"scene_id": scene_id, "seed": int(seed), "spec_digest": spec.digest()}
    return out if storeys == 1 else {**out, "storeys": int(storeys)}


def scan_versions() -> list[int]:
    """[scanner version, trajectory version]: in the key of every cache made from scans (training
    frames, episodes), so frames or episodes of an older scan are made again with the scan."""
    from calnav.envs.scanning.config import SCANNER_VERSION
    from calnav.envs.trajectories import TRAJECTORY_VERSION

    return [SCANNER_VERSION, TRAJECTORY_VERSION]


def scanned_identity(scene_id: str, seed: int, spec: HouseSpec, cfg: DatasetConfig) -> dict:
    """The metadata that makes a scan's cache file the scan of this house with these settings
    (``scan_house`` writes the scan keys, JSON-normalised here as they are read back)."""
    scanner, trajectory = scan_versions()
    scanning = json.loads(json.dumps(cfg.scanning.digest_items(), default=list))
    return {**procedural_identity(scene_id, seed, spec), "scan_seed": int(seed), "scanner_version": scanner,
            "trajectory_version": trajectory, "scanning": scanning}


def _load_procedural(scene_id: str, path: Path, seed: int, spec: HouseSpec, storeys: int = 1) -> Scene:
    scene = cached_scene(path, procedural_identity(scene_id, seed, spec, storeys))
    if scene is not None:
        return scene
    scene = generate_house(seed, spec, storeys=storeys)
    scene.name = scene_id
    scene.meta["scene_id"] = scene_id
    path.parent.mkdir(parents=True, exist_ok=True)
    save_atomic(scene, path)
    return scene


def _load_scanned(path: Path, clean_loader, identity: dict, seed: int, cfg: DatasetConfig) -> Scene:
    """The cached scan at ``path`` when it holds ``identity`` (``scanned_identity``), or scan the
    clean house (``clean_loader()``) and cache it."""
    from calnav.envs.scanning.scanner import scan_house

    scene = cached_scene(path, identity)
    if scene is not None:
        return scene
    scene = scan_house(clean_loader(), cfg.scanning, seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_atomic(scene, path)
    return scene


def clear_scene_lru() -> None:
    """Forget the in-process scene LRU (the on-disk cache stays)."""
    _lru.clear()
