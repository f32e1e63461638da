"""The ``calnav`` command line. Each subcommand lives in its own module; this file only parses
arguments and dispatches, so ``calnav --help`` stays fast (heavy imports happen on use)."""
from __future__ import annotations

import argparse
import importlib
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

# torch's OpenMP workers spin after each op and starve Open3D's threads on small machines
# (measured: 400-900 ms instead of 2 ms per segmenter frame on 2 busy cores). Must be set
# before torch is imported.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from calnav.common.interrupt import sigint_flag
from calnav.eval.config import (CALIBRATION_SECTIONS, EPISODE_SECTIONS, MAP_SECTIONS, PREDICTOR_SECTIONS,
                                SEGMENTER_SECTIONS, ConfigError)
from calnav.eval.results_dir import ResultsError
from calnav.eval.parser import build_parser
from calnav.eval.sections import QUICK_PRESET
from calnav.eval.shorthands import Schema, Shorthand, fixed


@dataclass(frozen=True)
class Command:
    """One ``calnav`` command: where it lives (imported on use so ``--help`` stays fast), the
    function that loads the configs it runs and its main, the sections of the root config it
    uses (``eval.config.Config``) and the arguments that set config keys. ``main`` (the CLI)
    loads the configs once, runs the preflight on them and hands the same objects to the
    command's main, so the preflight checks exactly the configs that run."""

    module: str
    main: str                 # main(args, configs) -> None, in module
    configs: str | None       # configs(args) -> list of configs, in module (or "other.module:function");
                              # None: the command reads no calnav config
    # the preflight's checks (eval.preflight.CHECKS) for what this command uses of its configs
    checks: tuple[str, ...] = ("run", "agent", "study", "mapping")
    sections: tuple[str, ...] = EPISODE_SECTIONS   # the root config's sections it uses (() with no config)
    shorthands: tuple[Shorthand, ...] = ()         # its arguments that set config keys (eval.shorthands)
    status: bool = False      # main returns the exit status (0 / 1: a check that found a difference)

    def load(self):
        """(main, configs loader), imported now."""
        main = getattr(importlib.import_module(self.module), self.main)
        if self.configs is None:
            return main, lambda args: []
        module, _, function = self.configs.rpartition(":")
        return main, getattr(importlib.import_module(module or self.module), function)

    def schema(self, name: str) -> Schema:
        return Schema(name, self.sections, self.shorthands)


def _lazy(ref: str) -> Callable[[Any], Any]:
    """The function ``module:function``, imported when first called (the table stays import-free)."""
    def call(value: Any) -> Any:
        module, _, function = ref.partition(":")
        return getattr(importlib.import_module(module), function)(value)
    return call


def _resolved(path: str) -> str:
    return str(Path(path).resolve())   # a list file named relative to where calnav was started


AGENT = Shorthand("--agent", "run.agent")
COMMANDS: dict[str, Command] = {
    "objectnav": Command("calnav.eval.objectnav.run", "main_objectnav", "objectnav_configs", shorthands=(AGENT,)),
    "start-pose": Command("calnav.eval.objectnav.start_pose", "main_start_pose", "start_pose_configs",
                          shorthands=(Shorthand("--workers", "run.workers"),)),
    "habitat-benchmark": Command("calnav.eval.habitat.run", "main_habitat_benchmark", "habitat_benchmark_configs",
                                 shorthands=(AGENT,)),
    "export-habitat": Command("calnav.eval.habitat.export", "main_export_habitat", "export_habitat_configs",
                              checks=("run",),   # runs no agent: generates episodes, writes files
                              shorthands=(Shorthand("--split", "env.split"),)),
    "view-episode": Command("calnav.eval.objectnav.view_episode", "main_view_episode", "view_episode_configs",
                            shorthands=(Shorthand("--agent", "run.agent", default="oracle"),)),  # the shortest path
    "scan-houses": Command("calnav.eval.scanning.run", "main_scan_houses", "scan_houses_configs",
                           checks=("run",),   # runs no agent: builds scans (splits checked by it)
                           shorthands=(fixed("env.dataset.style", "scanned"),)),
    "check-scene": Command("calnav.eval.scanning.check", "main_check_scene", "check_scene_configs",
                           checks=("run",),   # runs no agent: loads scenes, builds navmeshes, draws episodes
                           shorthands=(Shorthand("target", "env.dataset.scene_dir",   # a scene file's or directory's
                                                 convert=_lazy("calnav.eval.scanning.check:target_scene_dir")),)),
    "bench": Command("calnav.eval.bench.run", "main_bench", None, sections=()),   # fixed workloads, no config
    "train-segmenter": Command("calnav.eval.segmenter.train", "main_train_segmenter",
                               "calnav.eval.segmenter.data:segmenter_configs", sections=SEGMENTER_SECTIONS),
    "eval-segmenter": Command("calnav.eval.segmenter.evaluate", "main_eval_segmenter",
                              "calnav.eval.segmenter.data:segmenter_configs", sections=SEGMENTER_SECTIONS),
    "collect-maps": Command("calnav.eval.prediction.collect", "main_collect_maps", "collect_configs",
                            shorthands=(Shorthand("--split", "env.split", default="train"),
                                        Shorthand("--steps", "env.max_episode_steps", convert=lambda n: n + 1,
                                                  default=250))),   # the rollout's STEPS steps fit the limit
    "train-predictor": Command("calnav.eval.prediction.train", "main_train_predictor", "train_predictor_configs",
                               checks=(),   # trains on collect-maps output: the config names no file or service
                               sections=PREDICTOR_SECTIONS,
                               shorthands=tuple(Shorthand(f"--{k.replace('_', '-')}", f"predictor_train.{k}")
                                                for k in ("epochs", "pos_weight", "seed", "val_fraction"))),
    "export-onnx": Command("calnav.eval.segmenter.export_onnx", "main_export_onnx", None, sections=()),  # a weight file
    "calibrate-map": Command("calnav.eval.calibration.study", "main_calibrate_map", "calibrate_map_configs",
                             sections=CALIBRATION_SECTIONS,
                             shorthands=(Shorthand("--quick", preset=QUICK_PRESET),
                                         Shorthand("--sequences", "sequences.list", convert=_resolved))),
    "fit-glfs": Command("calnav.eval.calibration.study", "main_fit_glfs", "fit_glfs_configs",
                        sections=CALIBRATION_SECTIONS,
                        shorthands=(Shorthand("--segmenter", "study.segmenters", convert=lambda name: f"[{name}]"),
                                    fixed("study.strategies", "[glfs]"))),   # it fits GLFS only
    "map": Command("calnav.eval.sequence.map_cmd", "main_map", "map_configs", sections=MAP_SECTIONS),
    "replay": Command("calnav.eval.sequence.replay", "main_replay", "replay_configs",
                      checks=("run", "agent", "mapping"),   # the agent's segmenter and files; no study
                      sections=(*EPISODE_SECTIONS, "sequence"),
                      shorthands=(Shorthand("--segmenter", "agent.segmenter", default="learned_rgb"),
                                  fixed("env.normalize_depth", "false"))),   # the recording's depth is metres
    "export-sequence": Command("calnav.eval.sequence.export", "main_export_sequence", "export_sequence_configs",
                               checks=("run",),   # segments nothing; its --scene is loaded first
                               sections=CALIBRATION_SECTIONS,
                               shorthands=(Shorthand("--resolution", "env.resolution", default="640x480"),
                                           Shorthand("--frames", "scan.frames",
                                                     convert=lambda n: n or None))),   # 0: the config's
    "tune": Command("calnav.eval.objectnav.tune", "main_tune", "tune_configs"),
    "study": Command("calnav.eval.objectnav.study", "main_study", "study_configs"),
    "report": Command("calnav.eval.objectnav.study_report", "main_report", None, sections=()),  # reads records
    "reproduce": Command("calnav.eval.objectnav.reproduce", "main_reproduce", "reproduce_configs", status=True),
    "compare": Command("calnav.eval.objectnav.compare", "main_compare", None, sections=()),  # reads runs' configs
    "demo": Command("calnav.eval.objectnav.demo", "main_demo", "demo_configs",
                    shorthands=(Shorthand("--output", "run.output_dir", default="runs/demo"),)),
    "view": Command("calnav.eval.sequence.view", "main_view", None, sections=()),   # reads recordings, no config
}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Parse ``argv`` (default: sys.argv[1:]). Options and KEY=VALUE overrides may be intermixed
    (``objectnav a.b=1 --episodes 0:2 c.d=2``): argparse's ``parse_intermixed_args`` does that,
    but not across subparsers, so the top-level parser only picks the command and the
    command's own parser reads the rest."""
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    args, _ = parser.parse_known_args(argv)   # the command (and --help / a bad command exit here)
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    rest = argv[argv.index(args.command) + 1:]
    # schema: the command's sections and shorthands, for its config loader (eval.shorthands.load_command_config)
    namespace = argparse.Namespace(command=args.command, schema=COMMANDS[args.command].schema(args.command))
    return sub.choices[args.command].parse_intermixed_args(rest, namespace=namespace)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        # a real Ctrl-C, told apart from a plugin's own KeyboardInterrupt (in the preflight's probe too)
        with sigint_flag():
            from calnav.envs.scene import check_cache_dir

            check_cache_dir()   # every command reads or writes the cache
            from calnav.eval.preflight import check_configs

            command = COMMANDS[args.command]
            command_main, load_configs = command.load()
            configs = load_configs(args)   # every config the command runs (all multirun combinations)
            check_configs(configs, command.checks)   # every file and service they name, before anything is written
            status = command_main(args, configs)
            if command.status and status:
                return int(status)
    except (ConfigError, ValueError, FileNotFoundError, ResultsError) as exc:
        print(f"calnav {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"calnav {args.command}: interrupted; finished work is kept: rerun the same command to resume",
              file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
