"""Preflight: open and validate every file a run's config names BEFORE the run writes anything
or starts a worker, so a bad file is one clear error (``calnav CMD: error: ...``, exit 2)
instead of a half-made results directory (whose ``config.yaml`` then refuses the corrected
rerun as "another config") or a ``BrokenProcessPool`` traceback from a worker.

Checked per config, by the loaders that own the data:

- the segmenter (``agent.segmenter`` with ``agent.segmenter_config``; for the calibration
  study every ``study.segmenters`` entry): its device and, for a learned one, its weight file
  (``agent.segmenters.check_segmenter``);
- ``mapping.glfs_params`` when set: readable, finite, valid, and for the segmenter's classes
  (``mapping.glfs.GLFSParams.load``);
- ``env.dataset.scene_dir`` when set: a directory holding scenes for the split(s) the run
  uses (``envs.scenes.split_scene_ids``);
- ``run.backend``: a known backend, and for ``ray`` an importable Ray (``eval.backends``).

``eval.cli`` calls ``check_command(args, COMMAND)`` for each command of ``COMMANDS`` once, just
before the command's main; it loads every config the command will run (all multirun
combinations) exactly as the command does. Like ``eval.cli`` it sits above the experiments (it
imports their config loading); no experiment imports it.
"""
from __future__ import annotations

from typing import Any

from eval.config import Config, load_config

COMMANDS: tuple[str, ...] = ("objectnav", "tune", "calibrate-map", "fit-glfs")


def check_run_resources(cfg: Any) -> None:
    """Validate the files ``cfg`` (a ``Config`` or ``CalibrateMapConfig``) names; raises
    ValueError / FileNotFoundError naming the file and what is wrong with it."""
    from agent.segmenters import check_segmenter
    from eval.backends import check_backend
    from mapping.glfs import GLFSParams

    check_backend(cfg.run.backend, cfg.run.ray_address)   # run.backend=ray without Ray: the install command

    if isinstance(cfg, Config):
        names = check_segmenter(cfg.agent.segmenter, cfg.agent.segmenter_config, cfg.run.device)
        if cfg.mapping.glfs_params:
            GLFSParams.load(cfg.mapping.glfs_params, class_names=names)
        if cfg.env.dataset.scene_dir:
            from envs.scenes import split_scene_ids

            split_scene_ids(cfg.env.split, cfg.env.dataset)
        return
    from eval.calibration.record import role_scene_ids

    for name in cfg.study.segmenters:
        check_segmenter(name, device=cfg.run.device)
    if cfg.mapping.glfs_params:   # the study fits its own GLFS; a named file must still be sound
        GLFSParams.load(cfg.mapping.glfs_params)
    role_scene_ids(cfg)


def command_configs(args, command: str) -> list[Any]:
    """Every config ``command`` (one of COMMANDS) will run for the parsed ``args``, loaded the
    way the command loads it."""
    if command == "objectnav":
        from eval.config import expand_multirun
        from eval.objectnav.run import agent_overrides

        combos = expand_multirun(list(args.overrides)) if getattr(args, "multirun", False) else [list(args.overrides)]
        return [load_config(args.config, agent_overrides(args, combo)) for combo in combos]
    if command == "tune":
        return [load_config(args.config, list(args.overrides))]
    from eval.calibration.config import CalibrateMapConfig

    if command == "calibrate-map":
        from eval.calibration.study import QUICK_OVERRIDES

        overrides = (list(QUICK_OVERRIDES) if args.quick else []) + list(args.overrides)
        return [load_config(args.config, overrides, cls=CalibrateMapConfig)]
    if command == "fit-glfs":
        return [load_config(args.config, [*args.overrides, f"study.segmenters=[{args.segmenter}]",
                                          "study.strategies=[glfs]"], cls=CalibrateMapConfig)]
    raise ValueError(f"no preflight for command {command!r}; valid: {', '.join(COMMANDS)}")


def check_command(args, command: str) -> None:
    """Load every config of ``command`` and check the files each names (see the module
    docstring). Call once, before the command writes anything or starts a worker."""
    for cfg in command_configs(args, command):
        check_run_resources(cfg)
