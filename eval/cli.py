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
from calnav.eval.sections import QUICK_PRESET
from calnav.eval.shorthands import Schema, Shorthand, fixed
from calnav.mapping.registry import LAYOUTS


def _add_config_args(p: argparse.ArgumentParser, default_config: str) -> None:
    p.add_argument("--config", default=default_config, help=f"YAML config (default: {default_config})")
    p.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                   help="dotted config overrides, e.g. env.resolution=160x120 mapping.fusion=glfs")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="calnav", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("objectnav", help="run ObjectNav episodes and report Success/SPL/SoftSPL/DTG")
    _add_config_args(p, "configs/objectnav.yaml")
    p.add_argument("--agent", default=None, metavar="NAME",
                   help="shorthand for run.agent=NAME (default: the config's, peanut)")
    p.add_argument("--episodes", default="10", help="N (first N) or A:B (a range) of the split's episodes")
    p.add_argument("--output", default=None, help="results directory (default: run.output_dir)")
    p.add_argument("--force", action="store_true", help="discard results of a different config in --output")
    p.add_argument("--video", type=int, default=0, metavar="N",
                   help="write <output>/videos/<episode_id>.mp4 for the first N episodes of the range (peanut)")
    p.add_argument("--rerun", type=int, default=0, metavar="N",
                   help="write <output>/rerun/<episode_id>.rrd (Rerun: camera, frames, 3D and 2D maps, metrics) for the "
                        "first N episodes of the range (peanut; needs the [viz] extra)")
    p.add_argument("-m", "--multirun", action="store_true",
                   help="cross product of comma-separated overrides (KEY=a,b), one subdirectory of --output "
                        "each, then comparison.md/.csv/.png")

    p = sub.add_parser("start-pose", help="the peanut agent under frame changes and rotated houses "
                                          "(is it equally good whatever the start pose?)")
    _add_config_args(p, "configs/objectnav.yaml")
    p.add_argument("--episodes", default="0:14", help="N (first N) or A:B (a range) of the split's episodes")
    p.add_argument("--variants", default="world,start,start_offset,start_rotated,house_yaw37",
                   help="comma-separated variants (eval.objectnav.start_pose.VARIANTS)")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes (shorthand for run.workers; default: the config's)")
    p.add_argument("--output", default="runs/start_pose", help="results directory")
    p.add_argument("--force", action="store_true", help="discard results of a different config in --output")

    p = sub.add_parser("habitat-benchmark", help="run an agent through habitat-lab's habitat.Benchmark on calnav "
                                                 "houses (needs habitat-lab: make habitat-setup)")
    _add_config_args(p, "configs/objectnav.yaml")
    p.add_argument("--habitat-config", default="configs/habitat_objectnav.yaml",
                   help="habitat-lab config (task, sensors, split); habitat.* overrides apply to it")
    p.add_argument("--agent", default=None, metavar="NAME",
                   help="shorthand for run.agent=NAME (default: the config's, peanut)")
    p.add_argument("--episodes", default="10", help="N (first N) or A:B (a range) of the split's episodes")
    p.add_argument("--output", default=None, help="results directory (default: run.output_dir)")
    p.add_argument("--force", action="store_true", help="discard results of a different config in --output")

    p = sub.add_parser("view-episode", help="top-down map PNG and a frame strip of one episode")
    _add_config_args(p, "configs/objectnav.yaml")
    p.add_argument("--episode", type=int, default=0, help="episode index within the split")
    p.add_argument("--agent", default=None, metavar="NAME",
                   help="agent whose path is drawn: oracle (default; the shortest path) or peanut; shorthand for "
                        "run.agent=NAME")
    p.add_argument("--output", default="runs/view", help="output directory")

    p = sub.add_parser("scan-houses", help="scan (and cache) the houses of splits for env.dataset.style=scanned; "
                                           "how scan-like they are (quality.csv / quality.md)")
    _add_config_args(p, "configs/objectnav.yaml")
    p.add_argument("--splits", default="val", help="comma-separated splits: train, val, test, calib (default: val)")
    p.add_argument("--houses", type=int, default=None, metavar="N", help="only the first N houses of each split")
    p.add_argument("--output", default="runs/scan_quality", help="results directory")
    p.add_argument("--force", action="store_true", help="discard results of a different config in --output")

    p = sub.add_parser("check-scene", help="what the simulator makes of a scene: walkable floor, navigable area, "
                                           "islands, passages too narrow for the agent, episodes generated / "
                                           "rejected; a top-down PNG (and a Rerun recording with the viz extra)")
    p.add_argument("target", help="a scene file (.ply / .npz), a directory of them, or a calnav scene id "
                                  "(house_val_0003; with env.dataset.style=scanned its scan)")
    _add_config_args(p, "configs/objectnav.yaml")
    p.add_argument("--episodes", type=int, default=20, help="episodes to generate per scene (default 20)")
    p.add_argument("--output", default="runs/check_scene", help="results directory")
    p.add_argument("--force", action="store_true", help="discard results of a different config in --output")

    p = sub.add_parser("bench", help="speed/memory figures as a flat JSON of name -> number")
    p.add_argument("--output", default="bench.json", help="JSON output path")
    p.add_argument("--only", default="", help="comma-separated sections (default: all)")
    p.add_argument("--quick", action="store_true", help="short run (indicative numbers only)")
    p.add_argument("--scene-seed", type=int, default=7, help="procedural house seed to measure on")

    p = sub.add_parser("train-segmenter", help="train a learned segmenter on frames of the train split")
    _add_config_args(p, "configs/segmenter.yaml")
    p.add_argument("--model", required=True, choices=("learned_rgb", "learned_rgbd"), help="network to train")
    p.add_argument("--output", default=None, help="weight file (default: agent/weights/<model>.pt)")
    p.add_argument("--resume", action="store_true", help="continue from this config's last epoch checkpoint")

    p = sub.add_parser("collect-maps", help="training maps for the target predictor: the agent explores train houses, "
                                            "partial maps + ground-truth goal cells every --every steps")
    _add_config_args(p, "configs/objectnav.yaml")
    p.add_argument("--split", default=None, choices=("train", "val"),
                   help="houses explored (val: held-out maps); shorthand for env.split (default train)")
    p.add_argument("--episodes", default="0:200", help="the split's episodes: N or A:B (default 0:200)")
    p.add_argument("--steps", type=int, default=None,
                   help="steps per episode (default 250); shorthand for env.max_episode_steps=STEPS+1")
    p.add_argument("--every", type=int, default=25, help="a snapshot every this many steps (default 25, PEANUT's)")
    p.add_argument("--output", required=True, help="results directory (episodes/<index>.npz; resumable)")
    p.add_argument("--force", action="store_true", help="discard the maps of a different config in --output")

    p = sub.add_parser("train-predictor", help="train the target predictor on collect-maps output; held-out AUC / AP")
    p.add_argument("--data", required=True, nargs="+", metavar="DIR", help="collect-maps directories (mixed)")
    p.add_argument("--output", default=None, help="weight file (default: agent/weights/predictor.pt)")
    p.add_argument("--val-data", nargs="+", default=None, metavar="DIR",
                   help="collect-maps directories of held-out houses (--split val) for the metrics; "
                        "default: --val-fraction of the training houses")
    p.add_argument("--val-fraction", type=float, default=None,
                   help="houses held out when there is no --val-data; shorthand for predictor_train.val_fraction "
                        "(default 0.15)")
    p.add_argument("--epochs", type=int, default=None,
                   help="passes over the training maps; shorthand for predictor_train.epochs (default 12)")
    p.add_argument("--pos-weight", type=float, default=None,
                   help="BCE weight of goal cells, [1, 1000]; shorthand for predictor_train.pos_weight (default 20; "
                        "PEANUT's released script 1, its weighted runs inverse frequency): goal cells are ~0.1-1 %% "
                        "of the unexplored cells")
    p.add_argument("--seed", type=int, default=None,
                   help="seed of the split, the initialisation and the batches; shorthand for predictor_train.seed "
                        "(default 0)")
    p.add_argument("--config", default=None, help="YAML config (default: none, the predictor_train defaults)")
    p.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                   help="dotted config overrides, e.g. predictor_train.lr=5e-4 (before --data, or after "
                        "another option: --data takes every word that follows it)")

    p = sub.add_parser("export-onnx", help="a learned segmenter as an ONNX model for the onnx adapter "
                                           "(checked against torch before it is written)")
    p.add_argument("--model", required=True, choices=("learned_rgb", "learned_rgbd"), help="network to export")
    p.add_argument("--weights", default=None, help="weight file (default: the shipped agent/weights/<model>.pt)")
    p.add_argument("--output", required=True, help="the .onnx file to write")

    p = sub.add_parser("eval-segmenter", help="accuracy / mIoU / ECE / mECE of a segmenter on held-out frames")
    _add_config_args(p, "configs/segmenter.yaml")
    p.add_argument("--model", required=True, metavar="SEGMENTER",
                   help="segmenter to score: gt | noisy | learned_rgb | learned_rgbd | hf | onnx | "
                        "package.module:factory | a calnav.segmenters plugin (configured by the segmenter section)")
    p.add_argument("--split", default="test", choices=("train", "val", "test"), help="split whose houses are rendered")
    p.add_argument("--frames", type=int, default=500, help="number of frames scored")
    p.add_argument("--output", default=None, help="metrics JSON path (default: print only)")

    p = sub.add_parser("calibrate-map", help="the map-calibration study: fusion strategies x calibration methods, "
                                             "results.csv / results.md / plots")
    _add_config_args(p, "configs/calibrate_map.yaml")
    p.add_argument("--quick", action="store_true",
                   help="small preset (3/1/3 houses, short fits), <= 5 minutes: sets the study / scan / glfs keys "
                        "of eval.sections.QUICK_PRESET")
    p.add_argument("--output", default=None, help="results directory (default: run.output_dir)")
    p.add_argument("--force", action="store_true", help="discard results of a different config in --output")
    p.add_argument("--sequences", default=None, metavar="LIST",
                   help="recorded sequences instead of calnav's houses: a list file of '<role> <dir> [layout]' lines "
                        "(role: calib_train | calib_val | test); shorthand for sequences.list=LIST")

    p = sub.add_parser("map", help="fuse a recorded RGB-D sequence (ScanNet / 7-Scenes layout, ROS bag) into a semantic map "
                                   "and score it against a labelled mesh")
    p.add_argument("sequence_dir", help="the recording's directory, or a ROS bag (--layout rosbag)")
    p.add_argument("--layout", required=True, choices=LAYOUTS.names(), help="file layout of the recording")
    p.add_argument("--segmenter", default=None, metavar="SEGMENTER",
                   help="segmenter run on every frame: gt | noisy | learned_rgb | learned_rgbd | hf | onnx | "
                        "package.module:factory | a calnav.segmenters plugin (segmenter section)")
    p.add_argument("--logits", default=None, metavar="DIR", help="precomputed logits DIR/N.npy|.npz (H, W, K)")
    p.add_argument("--classes", default=None, metavar="FILE",
                   help="class list of --logits (.json list or one name per line; default DIR/classes.json|.txt)")
    p.add_argument("--labels-ply", default=None, metavar="PLY",
                   help="labelled ground-truth mesh (default: *_vh_clean_2.labels.ply in the sequence directory)")
    p.add_argument("--config", default=None, help="YAML config (default: configs/map_sequence.yaml)")
    p.add_argument("--output", required=True, help="results directory")
    p.add_argument("--force", action="store_true", help="replace the results of another config in --output")
    p.add_argument("--rerun", action="store_true",
                   help="also write <output>/map.rrd (Rerun: frames, poses, the map by class / confidence, correct vs "
                        "wrong voxels, the mesh; needs the [viz] extra)")
    p.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                   help="dotted config overrides, e.g. mapping.fusion=glfs sequence.frame_stride=2")

    p = sub.add_parser("replay", help="what the ObjectNav agent would do on a recording (ROS bag, ScanNet / 7-Scenes "
                                      "layout), open loop: per-frame actions, detections, goals, STOPs; the map")
    p.add_argument("recording", help="a ROS bag (--layout rosbag, the default) or a recording's directory")
    p.add_argument("--goal", required=True, help="the goal category searched (name or id: chair, bed, plant, ...)")
    p.add_argument("--layout", default="rosbag", choices=LAYOUTS.names(), help="file layout of the recording")
    p.add_argument("--segmenter", default=None, metavar="SEGMENTER",
                   help="shorthand for agent.segmenter (default learned_rgb: a recording has no ground-truth labels)")
    p.add_argument("--config", default=None, help="YAML config of the agent (default: configs/objectnav.yaml)")
    p.add_argument("--output", required=True, help="results directory")
    p.add_argument("--force", action="store_true", help="replace the results of another config in --output")
    p.add_argument("--rerun", action="store_true",
                   help="also write <output>/replay.rrd (Rerun: frames, camera, maps, goals; needs the [viz] extra)")
    p.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                   help="dotted config overrides, e.g. agent.goal_threshold=0.9 sequence.frame_stride=2")

    p = sub.add_parser("export-sequence", help="write calnav's own frames (a house's calibration scan) in "
                                               "ScanNet layout, with a labelled mesh")
    _add_config_args(p, "configs/calibrate_map.yaml")
    p.add_argument("--scene", default="house_val_0000", help="scene id (default: house_val_0000)")
    p.add_argument("--frames", type=int, default=None,
                   help="scan length, frames; shorthand for scan.frames (default: the config's; 0 = the config's)")
    p.add_argument("--resolution", default=None,
                   help="frame size WxH, pixels; shorthand for env.resolution (default 640x480)")
    p.add_argument("--max-edge", type=float, default=0.05,
                   help="ground-truth mesh: longest edge after subdivision, metres (default 0.05)")
    p.add_argument("--output", required=True, help="output directory (must be empty unless --force)")
    p.add_argument("--force", action="store_true", help="write into a non-empty --output")

    p = sub.add_parser("fit-glfs", help="record calibration scans and train GLFS parameters for one segmenter")
    _add_config_args(p, "configs/calibrate_map.yaml")
    p.add_argument("--segmenter", required=True, metavar="SEGMENTER",
                   help="segmenter whose observations GLFS is fitted to (any agent.segmenter spec; segmenter "
                        "section); shorthand for study.segmenters=[SEGMENTER]")
    p.add_argument("--output", required=True, help="GLFS parameter file (.json / .npz) for mapping.glfs_params")
    p.add_argument("--work-dir", default=None, help="where scans are kept (default: run.output_dir)")
    p.add_argument("--variant", default=None,
                   help="GLFS variant of study.glfs_variants to train (default: the first, 'learned' = the glfs section)")

    p = sub.add_parser("tune", help="grid-search agent.goal_threshold x agent.goal_min_area_cells (peanut agent); "
                                    "tune.csv + best.yaml")
    _add_config_args(p, "configs/objectnav.yaml")
    p.add_argument("--episodes", default="0:100", help="tuning range of the split's episodes: N or A:B")
    p.add_argument("--thresholds", default="0.5,0.6,0.7,0.8,0.9",
                   help="comma-separated goal confidence thresholds, each in (0, 1]")
    p.add_argument("--min-areas", default="2,4,8", help="comma-separated minimum goal areas, map cells (>= 1)")
    p.add_argument("--metric", default="spl", choices=("spl", "success", "softspl"), help="selection metric")
    p.add_argument("--extend", type=int, default=0,
                   help="while the best threshold is on the grid's edge, try up to this many more beyond it")
    p.add_argument("--output", default="runs/tune", help="results directory (one subdirectory per grid point)")
    p.add_argument("--force", action="store_true", help="discard results of a different config in --output")

    p = sub.add_parser("study", help="the ObjectNav study of a study config: tune each row's goal threshold, "
                                     "evaluate on held-out episodes, write manifest.json (resumable)")
    p.add_argument("study", help="study config (YAML; e.g. configs/study.yaml)")
    p.add_argument("overrides", nargs="*", help="config overrides of every row, e.g. run.workers=2")
    p.add_argument("--output", default="runs/study", help="results directory (tune/, eval/, manifest.json)")
    p.add_argument("--rows", default="", help="comma-separated row names to run (default: every row)")
    p.add_argument("--force", action="store_true", help="discard results of a different config in --output")

    p = sub.add_parser("report", help="a study's results page (results.md, threshold_curves.png) from its manifest "
                                      "and records")
    p.add_argument("manifest", help="the manifest.json `calnav study` wrote")
    p.add_argument("--output", default="", help="directory for results.md (default: the manifest's)")

    p = sub.add_parser("compare", help="one comparison table (+ paired differences) from finished objectnav runs")
    p.add_argument("runs", nargs="+", help="run directories (each with config.yaml and episodes.jsonl)")
    p.add_argument("--keys", default="", help="comma-separated config keys as columns (default: the keys that differ)")
    p.add_argument("--baseline", type=int, default=0, help="position of the run the paired differences are taken against")
    p.add_argument("--output", required=True, help="directory for comparison.md/.csv/.png and paired.md/.csv")

    p = sub.add_parser("view", help="open Rerun recordings (.rrd, a map.npz, or a results directory's) in the Rerun "
                                    "viewer, or print the command where there is no display (needs the [viz] extra)")
    p.add_argument("path", help="an .rrd file, a calnav map map.npz, or a results directory")
    p.add_argument("--print", action="store_true", help="print the viewer command instead of starting it")

    p = sub.add_parser("demo", help="set-up check + a real ObjectNav evaluation on procedural houses")
    p.add_argument("--episodes", type=int, default=5, help="number of val episodes")
    p.add_argument("--output", default=None, help="results directory; shorthand for run.output_dir (default runs/demo)")
    p.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                   help="dotted config overrides of configs/demo.yaml, e.g. run.workers=2")
    return parser


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
            command_main(args, configs)
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
