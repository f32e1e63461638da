"""Preflight: open and validate every file and service a command's configs name BEFORE the
command writes anything or starts a worker, so a bad file is one clear error (``calnav CMD:
error: ...``, exit 2) instead of a half-made results directory (whose ``config.yaml`` then
refuses the corrected rerun as "another config") or a ``BrokenProcessPool`` traceback from a
worker.

``eval.cli`` runs it for every command: the command registry (``eval.cli.COMMANDS``) names, per
command, the function that loads the configs the command runs; the CLI loads them once, hands
them to ``check_configs`` and then to the command's main, so what is checked is exactly what
runs. Checked per config (``eval.config.Config``), by the sections it holds (the command's) and
the checks the command declares, with the loaders that own the data:

- ``run``: a known backend, for ``ray`` an importable Ray and a reachable address
  (``eval.backends.check_backend``); a torch device other than cpu must exist;
- ``agent`` (the episode configs): the segmenter's device and, for a learned one, its weight
  file (``agent.segmenters.check_segmenter``; its settings: the ``segmenter`` section); a
  segmenter that reads the ground-truth semantic image only with a semantic sensor (the habitat
  config's, for habitat-benchmark); ``env.dataset.scene_dir`` when set: a directory holding
  scenes for the split the episodes come from (``envs.scenes.split_scene_ids``);
- ``study`` (the calibration study): every ``study.segmenters`` entry (predicting every calnav
  class), and the houses or
  recorded sequences of every role (``eval.calibration.record.role_scene_ids``);
- ``mapping.glfs_params`` when set: readable, finite, valid, and for the segmenter's classes
  (``mapping.glfs.GLFSParams.load``);
- first of all, the memory one worker of the run needs (the agent's 2D map, the voxel map, the
  navigation grid of the largest house, the renderer's buffers) against the memory available
  (``eval.memory.check_memory``).

Other objects a command runs with (habitat-lab's own config) are validated by their loaders.
Like ``eval.cli`` it sits above the experiments; no experiment imports it.
"""
from __future__ import annotations

from dataclasses import is_dataclass
from typing import Any, Iterable


CHECKS: tuple[str, ...] = ("run", "agent", "study", "mapping")   # the sections checked, by default all


def check_run_resources(cfg: Any, checks: tuple[str, ...] = CHECKS) -> None:
    """Validate the files and services ``cfg`` (any command's config dataclass) names, in the
    sections of ``checks`` (those the command uses); raises ValueError / FileNotFoundError naming
    the file and what is wrong with it."""
    from calnav.agent.segmenters import check_segmenter
    from calnav.eval.backends import check_backend
    from calnav.mapping.glfs import GLFSParams

    unknown = set(checks) - set(CHECKS)
    if unknown:
        raise ValueError(f"unknown preflight checks {sorted(unknown)}; valid: {', '.join(CHECKS)}")
    if not is_dataclass(cfg):
        return
    from calnav.eval.memory import check_memory

    check_memory(cfg, checks)   # the memory one worker needs (maps, grids, buffers), before any file is opened
    run = getattr(cfg, "run", None)
    if run is not None and "run" in checks:
        check_backend(run.backend, run.ray_address)   # run.backend=ray without Ray: the install command
        if run.device != "cpu":
            from calnav.agent.segmenters.base import resolve_device

            resolve_device(run.device, "run.device")
    names = None
    agent = getattr(cfg, "agent", None) if "agent" in checks else None
    if agent is not None:
        from calnav.agent.segmenters.base import task_goal_categories

        goals = task_goal_categories(agent)
        if cfg.env.dataset.data_path:
            check_episode_file(cfg.env, goals)
        names = check_segmenter(agent.segmenter, cfg.segmenter, run.device if run else None,
                                probe_size=tuple(cfg.env.resolution), goals=goals)
        if agent.exploration == "prediction" and getattr(run, "agent", "peanut") == "peanut":
            from calnav.agent.prediction import DEFAULT_PREDICTOR, check_predictor

            check_predictor(agent.predictor_weights or DEFAULT_PREDICTOR, names,
                            tuple(g for g in goals if g in names), agent.cell_m)
        _check_sensors_feed_the_segmenter(cfg)
        if not agent.stop_margin_m < cfg.env.view_point_radius_m:
            raise ValueError(f"agent.stop_margin_m ({agent.stop_margin_m} m) must be below env.view_point_radius_m "
                             f"({cfg.env.view_point_radius_m} m): the agent stops within the difference of the goal")
        if not agent.collision_min_move_m < cfg.env.forward_step_m:
            raise ValueError(f"agent.collision_min_move_m ({agent.collision_min_move_m:g} m) must be below "
                             f"env.forward_step_m ({cfg.env.forward_step_m:g} m): every forward step would count as a "
                             "collision")
        if cfg.env.dataset.scene_dir and not cfg.env.dataset.data_path:
            from calnav.envs.scenes import split_scene_ids

            split_scene_ids(cfg.env.split, cfg.env.dataset)
    study = getattr(cfg, "study", None) if "study" in checks else None
    if study is not None:
        from calnav.agent.segmenters.base import default_class_names

        calnav = default_class_names()
        for name in study.segmenters:
            predicted = check_segmenter(name, getattr(cfg, "segmenter", None), device=run.device if run else None)
            if predicted != calnav:   # the study scores its maps against labels of every calnav class
                missing = [n for n in calnav if n not in predicted]
                raise ValueError(f"study.segmenters: segmenter {name} predicts no {', '.join(missing)}; the "
                                 "calibration study needs every calnav class: map the model's classes to calnav's "
                                 "with segmenter.label_map")
    mapping = getattr(cfg, "mapping", None) if "mapping" in checks else None
    if mapping is not None and mapping.glfs_params:   # a study fits its own GLFS; a named file must still be sound
        GLFSParams.load(mapping.glfs_params, class_names=names)
    if study is not None:
        from calnav.eval.calibration.record import role_scene_ids

        role_scene_ids(cfg)


def check_episode_file(env_cfg: Any, goals: tuple[str, ...]) -> None:
    """A habitat-lab episode file (``env.dataset.data_path``) is read whole before anything is
    written: every file of the split parses, its categories are the agent's ``goals`` (by
    objectgoal id), and every scene it names resolves under ``env.dataset.scene_dir``."""
    from calnav.envs.episode_datasets import read_dataset, resolve_scene

    dataset = read_dataset(env_cfg.dataset.data_path, env_cfg.split)
    names = dataset.source.category_names
    if names != tuple(goals):
        raise ValueError(f"{dataset.source.path}: its objectgoal ids name {', '.join(names)}, but the agent's goal "
                         f"categories are {', '.join(goals)}; set agent.goal_categories=[{','.join(names)}] (and a "
                         "segmenter that predicts them)")
    for scene_id in dataset.scene_ids():
        resolve_scene(scene_id, env_cfg.dataset.scene_dir)


def _check_sensors_feed_the_segmenter(cfg: Any) -> None:
    """A map agent whose segmenter reads the ground-truth semantic image needs a semantic sensor
    (else every episode crashes on its first step: a table of errors, or a habitat-lab traceback)."""
    from calnav.agent.segmenters import segmenter_needs_semantic

    if cfg.run.agent == "peanut" and not cfg.env.semantic_sensor and segmenter_needs_semantic(cfg.agent.segmenter):
        raise ValueError(f"agent.segmenter={cfg.agent.segmenter} reads the ground-truth semantic observation, but "
                         "this run has no semantic sensor (env.semantic_sensor is false; habitat-benchmark: the "
                         "habitat config's sensors); use agent.segmenter=learned_rgb | learned_rgbd, or a semantic "
                         "sensor (env.semantic_sensor=true; habitat-benchmark: --habitat-config "
                         "configs/habitat_objectnav_semantic.yaml)")


def check_configs(configs: Iterable[Any], checks: tuple[str, ...] = CHECKS) -> None:
    """``check_run_resources`` for every config a command will run (all multirun combinations)."""
    for cfg in configs:
        check_run_resources(cfg, checks)
