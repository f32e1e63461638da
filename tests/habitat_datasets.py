"""ObjectNav episode files written by habitat-lab's own classes (``ObjectNavDatasetV1``,
``ObjectGoalNavEpisode``, ``ObjectGoal``, ``ObjectViewLocation``, ``AgentState``, and its
``to_json`` with its float encoder), for the tests that read them back with calnav. Needs
habitat-lab (``.venv-habitat``)."""
from __future__ import annotations

import gzip
from pathlib import Path


def habitat_lab_dataset(episodes: list[dict], goals_by_category: dict[str, list[dict]],
                        categories: dict[str, int]):
    """An ``ObjectNavDatasetV1`` built from plain dicts: ``episodes`` with ``episode_id``,
    ``scene_id``, ``start_position`` (3,), ``start_rotation`` (4,), ``object_category``, ``info``;
    goals (per ``<scene basename>_<category>``) with ``object_id``, ``object_category``,
    ``position`` and ``view_points`` [(x, y, z), ...] in Habitat's frame."""
    from calnav.common.habitat_import import import_habitat

    import_habitat()
    from habitat.core.simulator import AgentState
    from habitat.datasets.object_nav.object_nav_dataset import ObjectNavDatasetV1
    from habitat.tasks.nav.object_nav_task import ObjectGoal, ObjectGoalNavEpisode, ObjectViewLocation

    ds = ObjectNavDatasetV1()
    ds.category_to_task_category_id = dict(categories)
    ds.category_to_scene_annotation_category_id = dict(categories)
    ds.goals_by_category = {
        key: [ObjectGoal(object_id=str(g["object_id"]), object_category=g["object_category"],
                         position=list(map(float, g["position"])),
                         view_points=[ObjectViewLocation(agent_state=AgentState(position=list(map(float, p)),
                                                                                rotation=[0.0, 0.0, 0.0, 1.0]),
                                                         iou=None) for p in g["view_points"]])
              for g in gs]
        for key, gs in goals_by_category.items()}
    ds.episodes = [ObjectGoalNavEpisode(episode_id=str(e["episode_id"]), scene_id=e["scene_id"],
                                        start_position=list(map(float, e["start_position"])),
                                        start_rotation=list(map(float, e["start_rotation"])),
                                        object_category=e["object_category"], info=dict(e["info"]),
                                        goals=list(ds.goals_by_category[e["goals_key"]]))
                   for e in episodes]
    return ds


def write_habitat_lab_split(root: Path, split: str, by_scene: dict[str, tuple[list[dict], dict]],
                            categories: dict[str, int]) -> str:
    """habitat-lab's layout written by habitat-lab: ``root/{split}/{split}.json.gz`` (no episodes,
    the category maps) and ``content/<scene>.json.gz`` per entry of ``by_scene`` ({file name:
    (episodes, goals_by_category)}); returns the ``data_path`` with ``{split}``."""
    base = root / split
    (base / "content").mkdir(parents=True, exist_ok=True)
    with gzip.open(base / f"{split}.json.gz", "wt") as f:
        f.write(habitat_lab_dataset([], {}, categories).to_json())
    for name, (episodes, goals) in by_scene.items():
        with gzip.open(base / "content" / f"{name}.json.gz", "wt") as f:
            f.write(habitat_lab_dataset(episodes, goals, categories).to_json())
    return str(root / "{split}" / "{split}.json.gz")


def load_with_habitat_lab(data_path: str, split: str, scenes_dir: str):
    """habitat-lab's own ``ObjectNavDatasetV1`` loaded from ``data_path`` (every scene)."""
    from calnav.common.habitat_import import import_habitat

    import_habitat()
    from habitat.config.default_structured_configs import DatasetConfig
    from habitat.datasets.object_nav.object_nav_dataset import ObjectNavDatasetV1
    from omegaconf import OmegaConf

    cfg = OmegaConf.structured(DatasetConfig(type="ObjectNav-v1", split=split, data_path=data_path,
                                             scenes_dir=scenes_dir))
    return ObjectNavDatasetV1(cfg)


def rewrite_with_habitat_lab(data_path: str, split: str, scenes_dir: str, out_root: Path) -> str:
    """The dataset at ``data_path`` loaded by habitat-lab and written again by habitat-lab
    (``to_json``, one content file per scene, as its releases are laid out) under
    ``out_root/{split}``; returns the new ``data_path``."""
    ds = load_with_habitat_lab(data_path, split, scenes_dir)
    base = out_root / split
    (base / "content").mkdir(parents=True, exist_ok=True)
    from habitat.datasets.object_nav.object_nav_dataset import ObjectNavDatasetV1

    head = ObjectNavDatasetV1()
    head.category_to_task_category_id = ds.category_to_task_category_id
    head.category_to_scene_annotation_category_id = ds.category_to_scene_annotation_category_id
    with gzip.open(base / f"{split}.json.gz", "wt") as f:
        f.write(head.to_json())
    for scene in sorted({ep.scene_id for ep in ds.episodes}):
        part = ObjectNavDatasetV1()
        part.category_to_task_category_id = ds.category_to_task_category_id
        part.category_to_scene_annotation_category_id = ds.category_to_scene_annotation_category_id
        part.episodes = [ep for ep in ds.episodes if ep.scene_id == scene]
        part.goals_by_category = {k: v for k, v in ds.goals_by_category.items()
                                  if k.startswith(Path(scene).name + "_")}
        with gzip.open(base / "content" / f"{Path(scene).name.split('.')[0]}.json.gz", "wt") as f:
            f.write(part.to_json())
    return str(out_root / "{split}" / "{split}.json.gz")
