"""`calnav export-habitat`: a split's houses and episodes in HM3D v0.2's layout with habitat-lab's
ObjectNav episode files (``envs.habitat_export``), so habitat-sim users run calnav's worlds, and
calnav reads them back through ``env.dataset.data_path`` as it reads HM3D.

Any split, style (``env.dataset.style``) and storey count (``env.dataset.storeys``); ``--scenes N``
exports the split's first N houses (default: all of ``env.dataset.<split>_scenes``). The
episodes are generated first (on the run's workers, as ``calnav objectnav`` generates them),
then each house is written in the driver (a Ray worker on another node would write to its own
disk). ``--output`` must be empty unless ``--force`` (an earlier export's files are rewritten).
"""
from __future__ import annotations

from pathlib import Path
from dataclasses import dataclass
from calnav.common.ranges import Range
from calnav.eval.arguments import REQUIRED, Command, arg


def export_habitat_configs(args) -> list:
    """The one config the export runs (``--split`` is ``env.split``)."""
    from calnav.eval.shorthands import load_command_config

    cfg = load_command_config(args)
    if cfg.env.dataset.data_path:
        raise ValueError("export-habitat writes calnav's generated houses; env.dataset.data_path names an episode "
                         "file already (unset it)")
    return [cfg]


def _check_output(out: Path, force: bool) -> Path:
    from calnav.eval.results_dir import check_output_dir

    out = check_output_dir(out)
    if out.exists() and any(out.iterdir()) and not force:
        raise ValueError(f"--output {out} is not empty; use an empty directory, or --force to write into it")
    return out


def main_export_habitat(args, configs: list) -> None:
    from dataclasses import replace

    from tqdm import tqdm

    from calnav.envs import habitat_export as hx
    from calnav.envs.navigation import NavGrid
    from calnav.envs.scenes import load_scene, split_scene_ids
    from calnav.envs.semantics import GOAL_CATEGORIES
    from calnav.eval.episodes import prepare_episodes

    cfg = configs[0]
    env = cfg.env
    out = _check_output(Path(args.output), args.force)
    scenes = split_scene_ids(env.split, env.dataset)
    if args.scenes is not None:
        if args.scenes > len(scenes):
            raise ValueError(f"--scenes {args.scenes}: split {env.split} has {len(scenes)} houses "
                             f"(env.dataset.{env.split}_scenes)")
        scenes = scenes[:args.scenes]
        env = replace(env, dataset=replace(env.dataset, **{f"{env.split}_scenes": len(scenes)}))
    episodes = prepare_episodes(env, cfg.run, upto=None)
    by_scene: dict[str, list] = {s: [] for s in scenes}
    for ep in episodes:
        by_scene[ep.scene_id].append(ep)
    contents = {}
    for index, scene_id in enumerate(tqdm(scenes, desc=f"writing {env.split} houses", unit="scene")):
        scene = load_scene(scene_id, env.dataset)
        hx.write_scene(scene, out, env.split, index, scene_id)
        placed = hx.with_floor_heights(NavGrid.build(scene, env), by_scene[scene_id])
        contents[scene_id] = hx.scene_content(placed, env.split, index, scene_id)
    split_file = hx.write_episodes(out, env.split, GOAL_CATEGORIES, contents)
    config = hx.write_dataset_config(out)
    where = hx.paths(out, env.split)
    print(f"exported {len(episodes)} {env.split} episodes in {len(scenes)} houses: {split_file}, {config}")
    print(f"read them back: calnav objectnav env.split={env.split} env.dataset.data_path='{where['data_path']}' "
          f"env.dataset.scene_dir={where['scene_dir']}")
    print(f"habitat-lab: habitat.dataset.data_path='{where['data_path']}' habitat.dataset.scenes_dir="
          f"{where['scene_dir']} habitat.simulator.scene_dataset={config}")


@dataclass
class ExportHabitatArgs:
    """``calnav export-habitat``'s flags."""

    split: str | None = arg(None, "shorthand for env.split (default: the config's, val)", sets="env.split")
    scenes: int | None = arg(None, "only the split's first N houses (default: all of env.dataset.<split>_scenes)",
                             metavar="N", range=Range(1, 1_000_000, "houses"))
    output: str = arg(REQUIRED, "the dataset's root, habitat-lab's data/ (must be empty unless --force)")
    force: bool = arg(False, "write into a non-empty --output")


COMMAND = Command(ExportHabitatArgs, main_export_habitat, export_habitat_configs, config="configs/objectnav.yaml",
                  checks=("run",))   # runs no agent: generates episodes, writes files
