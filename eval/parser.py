"""The ``calnav`` argument parser: every command's arguments (``eval.cli`` dispatches them).
Only argparse and the registries' names load here, so ``calnav --help`` stays fast."""
from __future__ import annotations

import argparse

from calnav.eval.sections import QUICK_PRESET
from calnav.mapping.registry import LAYOUTS


DESCRIPTION = ("ObjectNav on a calibrated semantic 3D map: run episodes, switch the fusion strategy, segmenter "
               "or calibration with one config key, and compare navigation and map-calibration metrics.")
EPILOG = ("Start with `calnav demo`; `calnav COMMAND --help` gives a command's options. The commands that run "
          "an agent or build a map take --config FILE and KEY=VALUE overrides (docs/configuration.md).")


def _add_config_args(p: argparse.ArgumentParser, default_config: str) -> None:
    p.add_argument("--config", default=default_config, help=f"YAML config (default: {default_config})")
    p.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                   help="dotted config overrides, e.g. env.resolution=160x120 mapping.fusion=glfs")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="calnav", description=DESCRIPTION, epilog=EPILOG)
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

    p = sub.add_parser("export-habitat", help="write a split's houses and episodes in HM3D v0.2's layout with "
                                              "habitat-lab ObjectNav episode files (for habitat-sim; read back "
                                              "with env.dataset.data_path)")
    _add_config_args(p, "configs/objectnav.yaml")
    p.add_argument("--split", default=None, help="shorthand for env.split (default: the config's, val)")
    p.add_argument("--scenes", type=int, default=None, metavar="N",
                   help="only the split's first N houses (default: all of env.dataset.<split>_scenes)")
    p.add_argument("--output", required=True, help="the dataset's root, habitat-lab's data/ (must be empty unless --force)")
    p.add_argument("--force", action="store_true", help="write into a non-empty --output")

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
    p.add_argument("--page", action="append", default=[], metavar="FILE",
                   help="a Markdown page whose '| figure | meaning | measured | target |' tables get this run's "
                        "figures (repeatable)")
    p.add_argument("--from", dest="source", default="", metavar="JSON",
                   help="render --page from this earlier bench output instead of measuring")

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
    p.add_argument("--page", action="append", default=[], metavar="FILE",
                   help="render FILE's '<!-- calnav calibrate-map DIR -->' tables from the committed records under DIR "
                        "(DIR/clean/results.csv, DIR/scanned/results.csv) instead of running the study; repeatable")

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
                   help="labelled ground-truth mesh (default: *_vh_clean_2.labels.ply in the sequence directory); its "
                        "labels read through sequence.label_map, else the label_map.json beside it")
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
    p.add_argument("--page", action="append", default=[], metavar="FILE",
                   help="a Markdown file whose '<!-- calnav report -->' ... '<!-- /calnav report -->' block becomes "
                        "the headline (metrics table and conclusions); repeatable, e.g. README.md")

    p = sub.add_parser("reproduce", help="rerun episodes of a results directory with its own config and compare "
                                         "every record field (exit 1 if one differs): does the code now give the "
                                         "same results?")
    p.add_argument("dir", help="a calnav objectnav results directory (config.yaml, episodes.jsonl), e.g. a study "
                               "row's eval/<row>/")
    p.add_argument("--episodes", required=True, help="N (first N) or A:B of the split's episodes; each must have a "
                                                     "record in DIR")
    p.add_argument("--output", default="", help="results directory of the rerun (default: a new temporary one)")
    p.add_argument("--force", action="store_true", help="discard results of a different config in --output")
    p.add_argument("--tol", type=float, default=1e-9, help="absolute tolerance of float fields (default 1e-9)")
    p.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                   help="only run.workers, run.backend, run.ray_address (a reproduction runs DIR's config)")

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
