"""Parsed episode files, cached: once per process and on disk beside the habitat-lab JSON.

``cached_episodes(path)`` is how calnav reads a scene's episode file (``envs.episode_files``'
layout): parsed once per process while the file stays the same, and from its binary sidecar
``<split>/parsed/<scene>.npz`` when that matches the file, so other processes skip the JSON
(every process of a run reads the split, and the JSON parse was ~1 s of each one's start-up).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calnav.common.atomic import atomic_path
from calnav.envs.episode_files import GoalObject, ObjectNavEpisode, read_episode_file


# ---------------------------------------------------------------- parsed once per process
# episode files already parsed in this process: path -> ((mtime_ns, size, inode), episodes). A
# command reads its split several times (preflight, feed order, the env); a rewritten file
# (another stat) is parsed again.
_PARSED: dict[Path, tuple[tuple[int, int, int], list[ObjectNavEpisode]]] = {}


def _stat_key(path: Path) -> tuple[int, int, int]:
    st = path.stat()
    return st.st_mtime_ns, st.st_size, st.st_ino


def cached_episodes(path: Path) -> list[ObjectNavEpisode] | None:
    """A scene's cached episodes, or None when the cache file is missing or damaged (a killed
    writer, another layout): the cache is rebuilt, as damaged scene caches are. Parsed once
    per process while the file stays the same (``_PARSED``), and read from its binary sidecar
    (``read_sidecar``) when that matches the file, so other processes skip the JSON."""
    try:
        key = _stat_key(path)   # before reading: a file rewritten meanwhile is parsed again next time
    except FileNotFoundError:
        return None
    hit = _PARSED.get(path)
    if hit is not None and hit[0] == key:
        return list(hit[1])   # (the episodes themselves are shared: nothing mutates them)
    episodes = read_sidecar(path, key)
    if episodes is None:
        try:
            episodes = read_episode_file(path)
        except (ValueError, FileNotFoundError):
            return None
        write_sidecar(path, key, episodes)
    _PARSED[path] = (key, episodes)
    return list(episodes)


# ---------------------------------------------------------------- the parsed sidecar
# A scene's parsed episodes beside its habitat-lab JSON file, in a form read ~50x faster.
#
# Why: every process of a run -- the driver and each pool or Ray worker -- reads its split, and
# parsing the JSON (``val``: 30 files, 51 MB, mostly the goals' view points) took ~1 s per
# process, a fixed cost paid again by every worker before its first episode. The sidecar holds
# the same numbers as arrays: ``<split dir>/parsed/<scene>.npz`` (never in ``content/``, which
# habitat-lab reads), written atomically by the first process that parses the JSON. It is a
# cache of the JSON, never a source: it records the JSON file's (mtime_ns, size, inode) and
# ``SIDECAR_FORMAT``, and anything that does not match, cannot be read, or does not hold
# consistent arrays is ignored (the JSON is parsed instead and the sidecar rewritten). No
# pickles: ``np.load(allow_pickle=False)``; strings travel as one JSON text.
SIDECAR_FORMAT = 1   # bump when ObjectNavEpisode / GoalObject change what they hold
# A house with storeys also stores heights and storeys (``STOREY_ARRAYS``); single-storey sidecars
# keep format 1 and their bytes.
STOREY_SIDECAR_FORMAT = 2
STOREY_ARRAYS = ("start_height", "storeys", "vp_heights")


def sidecar_path(content_file: Path) -> Path | None:
    """``<split>/content/<scene>.json.gz`` -> ``<split>/parsed/<scene>.npz``; None for a file
    outside a split's ``content`` folder (no sidecar: it is not calnav's cache)."""
    if content_file.parent.name != "content" or not content_file.name.endswith(".json.gz"):
        return None
    return content_file.parent.parent / "parsed" / f"{content_file.name.removesuffix('.json.gz')}.npz"


def write_sidecar(content_file: Path, source_key: tuple[int, int, int], episodes: list) -> None:
    """Store ``episodes`` (parsed from ``content_file`` whose stat key was ``source_key``); a
    cache that cannot be written (read-only, full disk) is skipped: the JSON stays the source."""
    path = sidecar_path(content_file)
    if path is None:
        return
    goals, index = [], {}
    for ep in episodes:
        for g in ep.goals:
            if id(g) not in index:
                index[id(g)] = len(goals)
                goals.append(g)
    ep_goals = [index[id(g)] for ep in episodes for g in ep.goals]
    strings = {"episode_id": [e.episode_id for e in episodes], "scene_id": [e.scene_id for e in episodes],
               "object_category": [e.object_category for e in episodes],
               "goal_category": [g.object_category for g in goals]}
    if any(e.scene_dataset_config for e in episodes):   # (an episode file's; calnav's own sidecars keep their bytes)
        strings["scene_dataset_config"] = [e.scene_dataset_config for e in episodes]
    arrays = {
        "format": np.array([SIDECAR_FORMAT, *source_key], np.int64),
        "strings": np.array(json.dumps(strings)),
        "start_position": np.array([e.start_position for e in episodes], np.float64).reshape(-1, 2),
        "start_rotation": np.array([e.start_rotation for e in episodes], np.float64).reshape(-1, 4),
        "distances": np.array([[e.geodesic_distance, e.euclidean_distance] for e in episodes],
                              np.float64).reshape(-1, 2),
        "ep_goal_offsets": np.cumsum([0] + [len(e.goals) for e in episodes]).astype(np.int64),
        "ep_goals": np.array(ep_goals, np.int64),
        "goal_id": np.array([g.object_id for g in goals], np.int64),
        "goal_position": np.array([g.position for g in goals], np.float64).reshape(-1, 3),
        "vp_offsets": np.cumsum([0] + [len(g.view_points) for g in goals]).astype(np.int64),
        "view_points": np.concatenate([np.asarray(g.view_points, np.float64).reshape(-1, 2) for g in goals]
                                      or [np.zeros((0, 2))]),
    }
    if any(e.start_storey or e.goal_storey or e.start_height for e in episodes) or any(
            g.view_point_heights is not None for g in goals):
        arrays["format"][0] = STOREY_SIDECAR_FORMAT
        arrays["start_height"] = np.array([e.start_height for e in episodes], np.float64)
        arrays["storeys"] = np.array([[e.start_storey, e.goal_storey] for e in episodes], np.int64).reshape(-1, 2)
        arrays["vp_heights"] = np.concatenate([g.heights() for g in goals] or [np.zeros(0)])
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            np.savez(tmp, **arrays)
    except OSError:
        pass


def read_sidecar(content_file: Path, source_key: tuple[int, int, int]) -> list | None:
    """The episodes stored for ``content_file`` at stat key ``source_key``, or None (no sidecar,
    another key or format, unreadable or inconsistent arrays)."""
    path = sidecar_path(content_file)
    if path is None or not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            a = {k: z[k] for k in z.files}
        fmt = int(a["format"][0])
        if a["format"].tolist()[1:] != [*source_key] or fmt not in (SIDECAR_FORMAT, STOREY_SIDECAR_FORMAT):
            return None
        storeyed = fmt == STOREY_SIDECAR_FORMAT
        s = json.loads(str(a["strings"]))
        n, ng = len(s["episode_id"]), len(s["goal_category"])
        eo, vo = a["ep_goal_offsets"], a["vp_offsets"]
        shapes_ok = (len(s["scene_id"]) == len(s["object_category"]) == n and a["start_position"].shape == (n, 2)
                     and a["start_rotation"].shape == (n, 4) and a["distances"].shape == (n, 2) and len(eo) == n + 1
                     and eo[0] == 0 and (np.diff(eo) >= 0).all() and eo[-1] == len(a["ep_goals"])
                     and ((a["ep_goals"] >= 0) & (a["ep_goals"] < ng)).all() and len(a["goal_id"]) == ng
                     and a["goal_position"].shape == (ng, 3) and len(vo) == ng + 1 and vo[0] == 0
                     and (np.diff(vo) >= 0).all() and vo[-1] == len(a["view_points"]))
        if storeyed:
            shapes_ok = shapes_ok and a["start_height"].shape == (n,) and a["storeys"].shape == (n, 2) \
                and a["vp_heights"].shape == (len(a["view_points"]),)
        if not shapes_ok:
            return None
        goals = [GoalObject(int(a["goal_id"][i]), s["goal_category"][i], a["goal_position"][i].copy(),
                            a["view_points"][vo[i]:vo[i + 1]].copy(),
                            a["vp_heights"][vo[i]:vo[i + 1]].copy() if storeyed else None) for i in range(ng)]
        shared: dict[tuple, list] = {}   # episodes with the same goals share one list, as parsed from JSON
        episodes = []
        for i in range(n):
            ids = tuple(a["ep_goals"][eo[i]:eo[i + 1]].tolist())
            episodes.append(ObjectNavEpisode(
                episode_id=s["episode_id"][i], scene_id=s["scene_id"][i], start_position=a["start_position"][i].copy(),
                start_rotation=a["start_rotation"][i].tolist(), object_category=s["object_category"][i],
                geodesic_distance=float(a["distances"][i, 0]), euclidean_distance=float(a["distances"][i, 1]),
                goals=shared.setdefault(ids, [goals[j] for j in ids]),
                scene_dataset_config=s.get("scene_dataset_config", [""] * n)[i],
                **({"start_height": float(a["start_height"][i]), "start_storey": int(a["storeys"][i, 0]),
                    "goal_storey": int(a["storeys"][i, 1])} if storeyed else {})))
        return episodes
    except Exception:  # noqa: BLE001 -- any damage to a cache file means: parse the JSON instead
        return None
