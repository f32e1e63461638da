"""habitat-lab's ObjectNav episode datasets, read from their own files (``env.dataset.data_path``).

The files are habitat-lab's ``ObjectNavDatasetV1`` layout (``objectnav_hm3d_v1``,
``objectnav_hm3d_v2``, ``objectnav_mp3d_v1``, or ``calnav export-habitat``'s), read in the order
and with the rules habitat-lab's loader uses, without habitat-lab:

- ``data_path`` with ``{split}`` replaced by ``env.split`` names the split file
  (``.../{split}/{split}.json.gz``). Its ``category_to_task_category_id`` is the task's category
  set (HM3D's 6, MP3D's 21): a category's ``objectgoal`` id. Its own ``episodes`` (most releases
  leave them empty) come first, then those of every per-scene file ``content/<scene>.json.gz``
  (the file's ``content_scenes_path``) in sorted scene order, each file's in file order: episode
  ``i`` of ``--episodes A:B`` is the ``i``-th of that concatenation, as in habitat-lab's
  ``dataset.episodes``.
- An episode's goals are ``goals_by_category[<basename of its scene_id>_<object_category>]``;
  a file without ``goals_by_category`` carries them in each episode (habitat-lab's
  ``dedup_goals`` case).
- ``scene_id`` resolves under ``env.dataset.scene_dir`` (habitat-lab's ``scenes_dir``) after
  habitat-lab's ``data/scene_datasets/`` prefix is stripped; a ``.basis.glb`` that is missing falls
  back to the ``.glb`` beside it (HM3D's two releases), and HM3D v0.2 files written with an
  ``hm3d_v0.2/`` prefix resolve against a ``hm3d/`` folder too. Last, a relative id is tried as
  it stands, from the working directory: habitat-lab writes back the ids it loaded joined to
  its (relative) ``scenes_dir``.
- habitat-lab renumbers ``episode_id`` to the index within its file; calnav keeps the file's own
  id, prefixed with the scene's name (``TEEsavR23oF:12``) unless the file's ids are unique already.

Positions are in Habitat's frame, (x, y up, z) = calnav's (x, z, -y) (``envs.episode_files``).
Every problem is a one-line ``ValueError`` naming the file and the entry, raised before a run
writes anything.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from calnav.envs.episode_files import ObjectNavEpisode, episodes_from_habitat, read_json_gz

SPLIT_KEY = "{split}"
HABITAT_SCENE_PREFIX = "data/scene_datasets/"        # habitat-lab's DEFAULT_SCENE_PATH_PREFIX, stripped
CONTENT_SCENES_PATH = "{data_path}/content/{scene}.json.gz"   # habitat-lab's default content_scenes_path
# HM3D v0.2's episode files name their scenes under hm3d_v0.2/ while its scene release unpacks to
# hm3d/ (and the other way round): both spellings are tried
HM3D_FOLDERS = ("hm3d_v0.2/", "hm3d/")
BASIS_SUFFIX = ".basis.glb"


@dataclass(frozen=True)
class DatasetFiles:
    """The files of one split of a habitat-lab ObjectNav dataset, found from its split file alone.

    path: the split file. categories: its ``category_to_task_category_id`` (name -> objectgoal
    id). files: the files the episodes come from, in habitat-lab's order (the split file first
    when it holds episodes). key: a hash of their paths, sizes and modification times (what a
    cache of their episodes is keyed by; ``eval.inputs`` fingerprints their contents).
    """

    path: Path
    split: str
    categories: dict[str, int]
    files: tuple[Path, ...]
    key: str

    @property
    def category_names(self) -> tuple[str, ...]:
        """The categories by objectgoal id (index = id)."""
        return tuple(sorted(self.categories, key=self.categories.get))


@dataclass(frozen=True)
class EpisodeDataset:
    """A split's episodes as its files state them, in habitat-lab's order
    (``ObjectNavEpisode.scene_id`` is the file's ``scene_id``, resolved by ``resolve_scene``)."""

    source: DatasetFiles
    episodes: tuple[ObjectNavEpisode, ...]

    def scene_ids(self) -> list[str]:
        """The distinct scene ids of the episodes, in the order they first appear."""
        return list(dict.fromkeys(ep.scene_id for ep in self.episodes))


def task_categories(env_cfg) -> tuple[str, ...]:
    """The task's goal categories by objectgoal id: the episode file's
    ``category_to_task_category_id`` when ``env.dataset.data_path`` is set, else calnav's."""
    from calnav.envs.semantics import GOAL_CATEGORIES

    if not env_cfg.dataset.data_path:
        return GOAL_CATEGORIES
    return dataset_files(env_cfg.dataset.data_path, env_cfg.split).category_names


def split_file(data_path: str, split: str) -> Path:
    """The split file ``data_path`` names for ``split`` (``{split}`` replaced); ValueError naming
    the path, and what lies beside it, when it is not a file."""
    if not data_path:
        raise ValueError("env.dataset.data_path is empty: name habitat-lab's episode file, e.g. "
                         "data/datasets/objectnav/hm3d/v1/{split}/{split}.json.gz")
    path = Path(data_path.replace(SPLIT_KEY, split)).expanduser()
    if path.is_file():
        return path
    parent = next((p for p in (path.parent, path.parent.parent) if p.is_dir()), None)
    present = sorted(q.name for q in parent.iterdir())[:10] if parent is not None else []
    where = f"; {parent} holds: {', '.join(present) or 'nothing'}" if parent is not None else ""
    raise ValueError(f"env.dataset.data_path {data_path!r} names no file for split {split!r} ({path} is "
                     f"missing){where}")


def _categories(data: dict, path: Path) -> dict[str, int]:
    cats = data.get("category_to_task_category_id")
    if not isinstance(cats, dict) or not cats:
        raise ValueError(f"episode file {path}: no category_to_task_category_id (habitat-lab's ObjectNav "
                         "datasets map each goal category to its objectgoal id there)")
    if not all(isinstance(k, str) and isinstance(v, int) and not isinstance(v, bool) for k, v in cats.items()):
        raise ValueError(f"episode file {path}: category_to_task_category_id must map names to int ids, got "
                         f"{dict(list(cats.items())[:3])}")
    ids = sorted(cats.values())
    if ids != list(range(len(ids))):
        raise ValueError(f"episode file {path}: category_to_task_category_id ids must be 0..{len(ids) - 1}, "
                         f"each once; got {ids}")
    annotation = data.get("category_to_scene_annotation_category_id", data.get("category_to_mp3d_category_id"))
    if isinstance(annotation, dict) and set(annotation) != set(cats):
        raise ValueError(f"episode file {path}: category_to_task_category_id and "
                         "category_to_scene_annotation_category_id name different categories (habitat-lab "
                         f"refuses this too): {sorted(set(cats) ^ set(annotation))}")
    return dict(cats)


def _content_files(split: Path, data: dict) -> list[Path]:
    """The per-scene files of the split, sorted by scene name (habitat-lab's
    ``_get_scenes_from_folder``); [] when the split file holds every episode itself."""
    pattern = str(data.get("content_scenes_path", CONTENT_SCENES_PATH))
    if "{scene}" not in pattern:
        raise ValueError(f"episode file {split}: content_scenes_path {pattern!r} has no {{scene}}")
    head, tail = pattern.split("{scene}", 1)
    folder = Path(head.format(data_path=str(split.parent)))
    if not folder.is_dir():
        return []
    found = sorted((p.name[:-len(tail)], p) for p in folder.iterdir() if p.name.endswith(tail) and p.is_file())
    return [p for _, p in found]


def _file_episodes(path: Path, data: dict) -> list[ObjectNavEpisode]:
    """The episodes of one file (``envs.episode_files.episodes_from_habitat``), a damaged entry
    one line naming the file."""
    if not isinstance(data.get("episodes", []), list):
        raise ValueError(f"episode file {path}: 'episodes' must be a list")
    try:
        return episodes_from_habitat(data)
    except KeyError as exc:
        raise ValueError(f"damaged episode file {path}: missing key {exc}") from None
    except (TypeError, IndexError, ValueError) as exc:
        raise ValueError(f"damaged episode file {path}: {exc}") from None


def _stat_key(files: list[Path]) -> str:
    h = hashlib.sha1()
    for p in files:
        st = p.stat()
        h.update(f"{p.resolve()}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()[:12]


def dataset_files(data_path: str, split: str) -> DatasetFiles:
    """The files of ``split`` of the dataset at ``data_path`` (module docstring), from its split
    file: its categories checked, its per-scene files listed."""
    path = split_file(data_path, split)
    data = read_json_gz(path)
    categories = _categories(data, path)
    files = ([path] if data.get("episodes") else []) + _content_files(path, data)
    if not files:
        raise ValueError(f"episode file {path} holds no episodes, and no content/<scene>.json.gz lies beside it")
    return DatasetFiles(path=path, split=split, categories=categories, files=tuple(files), key=_stat_key(files))


def read_dataset(data_path: str, split: str) -> EpisodeDataset:
    """Every episode of ``split`` of the dataset at ``data_path`` (module docstring), each file
    read and checked: every episode's category is in the category map and has its goals."""
    source = dataset_files(data_path, split)
    episodes = []
    for path in source.files:
        episodes.extend(_file_episodes(path, read_json_gz(path)))
    if not episodes:
        raise ValueError(f"episode file {source.path} and the content files beside it hold no episodes")
    for ep in episodes:
        if ep.object_category not in source.categories:
            raise ValueError(f"episode {ep.episode_id} of {ep.scene_id}: category {ep.object_category!r} is not in "
                             f"{source.path.name}'s category_to_task_category_id ({', '.join(source.categories)})")
    return EpisodeDataset(source=source, episodes=tuple(_unique_ids(episodes)))


def _unique_ids(episodes: list[ObjectNavEpisode]) -> list[ObjectNavEpisode]:
    """The episodes with calnav's episode ids: the file's own when they are unique across the
    dataset, else ``<scene name>:<file id>`` (HM3D numbers each scene's episodes from 0)."""
    ids = [ep.episode_id for ep in episodes]
    if len(set(ids)) == len(ids):
        return episodes
    seen: set[str] = set()
    for ep in episodes:
        joined = f"{scene_name(ep.scene_id)}:{ep.episode_id}"
        if joined in seen:
            raise ValueError(f"episode id {ep.episode_id!r} appears twice in the episodes of scene {ep.scene_id}; "
                             "habitat-lab would run both but calnav's records could not tell them apart: give "
                             "each episode of a scene its own episode_id")
        seen.add(joined)
    for ep in episodes:
        ep.episode_id = f"{scene_name(ep.scene_id)}:{ep.episode_id}"
    return episodes


def scene_name(scene_id: str) -> str:
    """The scene's name: its file's stem without ``.basis`` (``hm3d/val/00800-TEEsavR23oF/
    TEEsavR23oF.basis.glb`` -> ``TEEsavR23oF``)."""
    name = PurePosixPath(scene_id).name
    for suffix in (BASIS_SUFFIX, ".glb", ".ply", ".npz"):
        if name.endswith(suffix):
            return name[:-len(suffix)]
    return name


def scene_candidates(scene_id: str, scenes_dir: str) -> list[Path]:
    """The files ``scene_id`` may name under ``scenes_dir``, in the order tried (module docstring)."""
    rel = scene_id[len(HABITAT_SCENE_PREFIX):] if scene_id.startswith(HABITAT_SCENE_PREFIX) else scene_id
    rel = rel[2:] if rel.startswith("./") else rel
    variants = [rel]
    for a, b in (HM3D_FOLDERS, HM3D_FOLDERS[::-1]):
        if rel.startswith(a):
            variants.append(b + rel[len(a):])
    root = Path(scenes_dir).expanduser()
    out = []
    # last, a relative id as it stands (from the working directory): habitat-lab writes back
    # the ids it loaded joined to a relative scenes_dir, which joined again names nothing
    tail = [Path(rel)] if not Path(rel).is_absolute() else []
    for p in [root / v if not Path(v).is_absolute() else Path(v) for v in variants] + tail:
        out.append(p)
        if p.name.endswith(BASIS_SUFFIX):
            out.append(p.with_name(p.name[:-len(BASIS_SUFFIX)] + ".glb"))
    return out


def resolve_scene(scene_id: str, scenes_dir: str) -> Path:
    """The scene file of ``scene_id`` (``scene_candidates``, the first that exists); ValueError
    naming the paths tried when none does."""
    tried = scene_candidates(scene_id, scenes_dir)
    for p in tried:
        if p.is_file():
            return p
    raise ValueError(f"scene {scene_id!r} of the episode file is missing under env.dataset.scene_dir "
                     f"{scenes_dir!r}: tried {', '.join(str(p) for p in tried)}")


def resolve_scene_config(config_id: str, scenes_dir: str) -> Path | None:
    """The scene dataset config an episode names (its ``scene_dataset_config``: habitat-lab's
    ``./data/scene_datasets/hm3d/hm3d_annotated_basis.scene_dataset_config.json``), found under
    ``scenes_dir`` as a scene id is (``scene_candidates``); None when the episode names none or
    it is not there: then the config in the scene's folder or a folder above it frames the
    scene, as habitat-sim falls back to its default dataset."""
    if not config_id:
        return None
    config_id = config_id[2:] if config_id.startswith("./") else config_id   # habitat-lab writes ./data/...
    return next((p for p in scene_candidates(config_id, scenes_dir) if p.is_file()), None)
