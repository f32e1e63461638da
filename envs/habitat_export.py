"""calnav's houses in HM3D v0.2's layout, with habitat-lab ObjectNav episode files
(``calnav export-habitat``)::

    <out>/scene_datasets/calnav/calnav.scene_dataset_config.json
    <out>/scene_datasets/calnav/<split>/<NNNNN>-<scene>/<scene>.glb, .semantic.glb, .semantic.txt
    <out>/datasets/objectnav/calnav/v1/<split>/<split>.json.gz          (category maps, no episodes)
    <out>/datasets/objectnav/calnav/v1/<split>/content/<scene>.json.gz  (a scene's episodes)

``<out>`` stands where habitat-lab's ``data/`` folder does: habitat-lab loads the episodes with
``data_path=<out>/datasets/objectnav/calnav/v1/{split}/{split}.json.gz`` and
``scenes_dir=<out>/scene_datasets`` (each episode's ``scene_id`` is
``calnav/<split>/<NNNNN>-<scene>/<scene>.glb`` and its ``scene_dataset_config``
``./data/scene_datasets/calnav/calnav.scene_dataset_config.json``, HM3D v0.2's form), and calnav
reads them back with ``env.dataset.data_path`` and ``env.dataset.scene_dir`` set the same. The
scenes are ``envs.hm3d_write``'s (z-up GLB coordinates, a baked colour texture, instance colours
in a semantic texture), the episodes ``envs.episode_files``' schema with the scene ids above,
positions in Habitat's frame with their floors' heights; ``NNNNN`` is the scene's index in its
split. habitat-sim builds the navmesh itself (``recompute_navmesh``): none is written.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from calnav.envs.episode_files import ObjectNavEpisode, episodes_to_habitat, write_json_gz

DATASET = "calnav"                                        # the scene dataset's folder and config name
EPISODES_DIR = ("datasets", "objectnav", DATASET, "v1")   # habitat-lab's objectnav/<dataset>/v1 layout
SCENE_DATASET_CONFIG = f"./data/scene_datasets/{DATASET}/{DATASET}.scene_dataset_config.json"


def scene_folder(split: str, index: int, scene_id: str) -> str:
    """``<split>/<NNNNN>-<scene>``: the scene's folder under the scene dataset."""
    return f"{split}/{index:05d}-{scene_id}"


def habitat_scene_id(split: str, index: int, scene_id: str) -> str:
    """The exported scene's ``scene_id`` in the episode files (relative to ``scenes_dir``)."""
    return f"{DATASET}/{scene_folder(split, index, scene_id)}/{scene_id}.glb"


def paths(out: Path, split: str) -> dict[str, Path | str]:
    """Where the export of ``split`` goes: the scene dataset root, the split's episode folder,
    and the ``data_path`` (with ``{split}``) / ``scene_dir`` to read it back with."""
    out = Path(out)
    episodes = out.joinpath(*EPISODES_DIR)
    return {"scenes": out / "scene_datasets" / DATASET, "episodes": episodes / split,
            "data_path": str(episodes / "{split}" / "{split}.json.gz"), "scene_dir": str(out / "scene_datasets")}


def write_scene(scene, out: Path, split: str, index: int, scene_id: str) -> dict[str, Path]:
    """Write one scene's files (``envs.hm3d_write.write_hm3d_scene``) into its folder."""
    from calnav.envs.hm3d_write import write_hm3d_scene

    return write_hm3d_scene(scene, paths(out, split)["scenes"] / scene_folder(split, index, scene_id), scene_id)


def with_floor_heights(navgrid, episodes: list[ObjectNavEpisode]) -> list[ObjectNavEpisode]:
    """``episodes`` with every start and view point at the height of the floor under it (where
    habitat-sim's navmesh puts an agent; a scanned house's floor is not at 0)."""
    import numpy as np

    if navgrid.layered:   # a house with storeys: its generator stored each floor height already
        return episodes
    goals: dict[int, object] = {}

    def lifted(g):
        if id(g) not in goals:
            goals[id(g)] = replace(g, view_point_heights=np.array([navgrid.floor_height(p) for p in g.view_points],
                                                                   np.float64))
        return goals[id(g)]

    return [replace(ep, start_height=navgrid.floor_height(ep.start_position), goals=[lifted(g) for g in ep.goals])
            for ep in episodes]


def scene_content(episodes: list[ObjectNavEpisode], split: str, index: int, scene_id: str) -> dict:
    """One scene's episodes as its habitat-lab content file (dict), under the exported scene id."""
    sid = habitat_scene_id(split, index, scene_id)
    content = episodes_to_habitat([replace(ep, scene_id=sid) for ep in episodes])
    for ep in content["episodes"]:
        ep["scene_dataset_config"] = SCENE_DATASET_CONFIG
    return content


def write_episodes(out: Path, split: str, categories: tuple[str, ...],
                   contents: dict[str, dict]) -> Path:
    """The split file (the category maps, no episodes) and ``contents`` ({scene id: its content
    file}) under ``out``'s episode folder; returns the split file."""
    folder = paths(out, split)["episodes"]
    for scene_id, content in contents.items():
        write_json_gz(folder / "content" / f"{scene_id}.json.gz", content)
    ids = {c: i for i, c in enumerate(categories)}
    split_file = folder / f"{split}.json.gz"
    write_json_gz(split_file, {"episodes": [], "category_to_task_category_id": ids,
                               "category_to_scene_annotation_category_id": ids})
    return split_file


def write_dataset_config(out: Path) -> Path:
    """habitat-sim's scene dataset config over every exported scene (``envs.hm3d_write``)."""
    from calnav.envs.hm3d_write import write_scene_dataset_config

    return write_scene_dataset_config(paths(out, "")["scenes"], name=DATASET)
