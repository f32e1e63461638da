"""A run's episodes, generated on its worker pool: only the scenes its episode range needs.

Episode indices are positions in the split's scenes concatenated in order (the habitat-lab
dataset order), so the range ``A:B`` needs the leading scenes up to the one holding ``B - 1``.
Those not cached yet are generated (and, for ``env.dataset.style=scanned``, scanned first) as
tasks of ``eval.runner.run_tasks`` on the run's backend, with its progress bar, instead of one
after another in the driver: a first ``--episodes 0:30`` on a fresh machine generates two
houses, not thirty.
"""
from __future__ import annotations

from dataclasses import dataclass

from calnav.envs.config import EnvConfig
from calnav.envs.episode_files import ObjectNavEpisode


@dataclass(frozen=True)
class SceneTask:
    """Generate one scene's episodes (a picklable task)."""

    split: str
    scene_id: str
    env_cfg: EnvConfig


def generate_scene_task(task: SceneTask) -> tuple[dict, dict]:
    """Generate ``task``'s scene (in a worker): ``envs.episodes.generate_scene``'s (report,
    content), which the driver caches: a worker on another Ray node needs no shared disk."""
    from calnav.envs.episodes import generate_scene

    return generate_scene(task.split, task.scene_id, task.env_cfg)


@dataclass(frozen=True)
class PlaceTask:
    """Place one scene of a habitat-lab episode file on calnav's navmesh (a picklable task)."""

    scene_id: str
    episodes: tuple   # ((dataset index, ObjectNavEpisode), ...): the scene's episodes as the file has them
    env_cfg: EnvConfig


def place_scene_task(task: PlaceTask) -> tuple[dict, dict]:
    """``envs.file_episodes.place_scene`` of ``task``'s scene (in a worker; the driver caches it)."""
    from calnav.envs.file_episodes import place_scene

    return place_scene(task.scene_id, list(task.episodes), task.env_cfg)


def prepare_file_episodes(env_cfg: EnvConfig, run_cfg, upto: int | None, progress: bool = True
                          ) -> list[ObjectNavEpisode]:
    """``prepare_episodes`` for a habitat-lab episode file (``env.dataset.data_path``): the
    scenes of episodes ``0:upto`` not placed yet are placed on ``run_cfg``'s backend, then the
    placed episodes are read (``envs.file_episodes``)."""
    from calnav.envs import file_episodes as fe
    from calnav.envs.episode_datasets import read_dataset
    from calnav.eval.runner import run_tasks

    dataset = read_dataset(env_cfg.dataset.data_path, env_cfg.split)
    root = fe.placement_dir(dataset.source, env_cfg)
    fe.write_index(root, dataset)
    _, todo = fe.scenes_to_place(dataset, env_cfg, upto)
    if todo:
        tasks = [PlaceTask(s, tuple(fe.scene_episodes(dataset, s)), env_cfg) for s in todo]
        failures = run_tasks(place_scene_task, tasks, run_cfg,
                             save=lambda task, result: fe.write_placed(root, task.scene_id, *result),
                             desc=f"placing {env_cfg.split} episodes", unit="scene", progress=progress)
        if failures:
            _raise_scene_failures(failures, env_cfg.split)
    return fe.load_dataset_split(env_cfg, progress=False, upto=upto)


def _raise_scene_failures(failures: list, split: str) -> None:
    """The first failed scene task's one-line reason (deterministic for the config: no "rerun
    to retry"), or its worker's traceback for an unexpected error."""
    failure = failures[0][1]
    more = f" ({len(failures) - 1} more scene(s) of {split} failed too)" if len(failures) > 1 else ""
    if failure.refusal:
        raise ValueError(failure.error.partition(": ")[2] + more)
    raise RuntimeError(f"preparing {failures[0][0].scene_id} failed{more}; the worker's traceback:\n"
                       f"{failure.traceback}")


def range_end(spec: str) -> int:
    """The end (exclusive) of an episode range 'N' or 'A:B', before any scene is generated;
    malformed or reversed ranges are refused here, with the valid forms."""
    from calnav.envs.episodes import parse_episode_range

    return parse_episode_range(str(spec), None).stop


def prepare_episodes(env_cfg: EnvConfig, run_cfg, upto: int | None, progress: bool = True
                     ) -> list[ObjectNavEpisode]:
    """The leading episodes of ``env_cfg.split`` that hold indices ``0:upto`` (every episode
    when None), generating the scenes they need on ``run_cfg``'s backend first."""
    from calnav.envs.episodes import check_read_back, scenes_needed, split_prefix, write_scene
    from calnav.eval.runner import run_tasks

    if env_cfg.dataset.data_path:
        return prepare_file_episodes(env_cfg, run_cfg, upto, progress)
    split, generated = env_cfg.split, set()
    while True:   # ends: every pass generates scenes not generated before, of finitely many
        needed, todo = scenes_needed(split, env_cfg, upto)
        if not todo:
            return split_prefix(split, env_cfg, needed)
        check_read_back(split, env_cfg, todo, generated)
        failures = run_tasks(generate_scene_task, [SceneTask(split, s, env_cfg) for s in todo], run_cfg,
                             save=lambda task, result: write_scene(split, task.scene_id, env_cfg, *result), desc=f"generating {split} episodes", unit="scene",
                             progress=progress)
        if failures:
            _raise_scene_failures(failures, split)
        generated.update(todo)


def episode_indices(spec: str, env_cfg: EnvConfig, run_cfg, progress: bool = True) -> range:
    """The indices of the episode range ``spec`` ('N' or 'A:B') of ``env_cfg.split``, its
    scenes generated first (``prepare_episodes``); a range past the split's end is refused with
    the split's size."""
    from calnav.envs.episodes import check_split_capacity, parse_episode_range

    if not env_cfg.dataset.data_path:   # (a file's size is known once it is read, below)
        check_split_capacity(str(spec), env_cfg.split, env_cfg)   # before generating scenes for nothing
    episodes = prepare_episodes(env_cfg, run_cfg, range_end(spec), progress)
    return parse_episode_range(str(spec), len(episodes))


def refused_episodes(env_cfg: EnvConfig, indices: list[int]) -> dict[int, str]:
    """{index: "<scene id>: <why>"} of the ``indices`` an episode file holds but calnav's navmesh cannot run
    (``envs.file_episodes``); {} for calnav's generated episodes (none is ever refused)."""
    if not env_cfg.dataset.data_path or not indices:
        return {}
    from calnav.envs.episodes import load_split

    episodes = load_split(env_cfg.split, env_cfg, progress=False, upto=max(indices) + 1)
    return {i: f"{episodes[i].scene_id}: {episodes[i].refused}" for i in indices if episodes[i].refused}


def other_recorded_episodes(env_cfg: EnvConfig, records_path, indices: list[int]) -> str | None:
    """How the records in ``records_path`` name other episodes than ``env_cfg.split`` holds
    under their indices now (``eval.stats.EPISODE_KEYS``: id and geodesic distance), in one
    line, or None when every one is the same. Scans, generated houses and their episodes are
    derived data: a scan made by another calnav version or on another machine places other
    starts under the same indices, and a run resumed on them would mix two datasets in one
    records file. Checked: every record up to the end of the range ``indices`` (the scenes it
    needs, read from the cache ``prepare_episodes`` filled before the run)."""
    from calnav.eval.records import read_records
    from calnav.eval.stats import EPISODE_KEYS

    if not indices:
        return None
    end = max(indices) + 1
    recorded = [r for i, r in sorted(read_records(records_path, quiet=True).records.items()) if i < end]
    if not recorded:
        return None
    from calnav.envs.episodes import load_split

    episodes = load_split(env_cfg.split, env_cfg, progress=False, upto=end)
    other = [(r, episodes[r["index"]]) for r in recorded if r["index"] < len(episodes)   # (the keys are its fields)
             and any(k in r and r[k] != getattr(episodes[r["index"]], k) for k in EPISODE_KEYS)]
    if not other:
        return None
    r, ep = other[0]
    was = f"{r.get('episode_id')} ({r.get('category', '?')}, {float(r.get('geodesic_distance', float('nan'))):.3f} m)"
    return (f"{len(other)} of its {len(recorded)} recorded episodes up to {end} are not the episodes the "
            f"{env_cfg.split} split holds now (episode {r['index']}: recorded {was}, now {ep.episode_id} "
            f"({ep.object_category}, {ep.geodesic_distance:.3f} m)): its houses, scans or episode file were made "
            "differently (by another calnav version, or scans made on another machine), and resuming would mix "
            "two datasets")


def check_file_scenes(cfg, indices: list[int]) -> None:
    """Refuse, in one line, a run of an episode file's ``indices`` whose agent needs what one of
    their scenes lacks (``envs.file_episodes``' per-scene ``lacks``): ground-truth semantics
    for a segmenter that reads them, RGB (Basis textures) for any other map agent's segmenter."""
    env_cfg = cfg.env
    if not env_cfg.dataset.data_path or not indices or getattr(cfg.run, "agent", "") != "peanut":
        return
    from calnav.agent.segmenters import segmenter_needs_semantic
    from calnav.envs.episode_datasets import read_dataset
    from calnav.envs.file_episodes import placement_report

    needs = "semantics" if segmenter_needs_semantic(cfg.agent.segmenter) else "rgb"
    dataset = read_dataset(env_cfg.dataset.data_path, env_cfg.split)
    reports = placement_report(dataset, env_cfg)
    for scene_id in dict.fromkeys(dataset.episodes[i].scene_id for i in indices if i < len(dataset.episodes)):
        why = reports.get(scene_id, {}).get("lacks", {}).get(needs)
        if why:
            what = "ground-truth semantics" if needs == "semantics" else "RGB"
            raise ValueError(f"agent.segmenter={cfg.agent.segmenter} needs {what}, which scene {scene_id} lacks: {why}")
