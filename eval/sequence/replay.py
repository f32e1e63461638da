"""``calnav replay RECORDING --goal NAME [--layout rosbag|scannet|7scenes]``: what the ObjectNav
agent would have done on a recording, open loop.

Every frame of the recording (a ROS bag, or any ``mapping.sequences`` layout; colour registered
to the depth camera) goes through the agent as a library (``agent.navigator.Navigator``: the
agent ``calnav objectnav`` runs, built from the same config keys) with the recorded camera
pose: perception, fusion, projection, detection and planning run as in an episode, but its
actions are not carried out -- the next frame is the recording's. The agent's sensor model is
the recording's depth camera: ``env.resolution`` is its size, ``env.hfov_deg`` its horizontal
field of view (from fx); ``env.normalize_depth`` is false (the command sets it: the recording's
depth is metres); the camera must be level (``agent.navigator.LEVEL_TOLERANCE_DEG``) at
``env.camera_height_m``. ``--segmenter`` (``agent.segmenter``) is ``learned_rgb`` unless given:
a recording has no ground-truth labels (``gt`` reads its ``semantic`` frames when it has them).

Writes to ``--output`` (a results directory, ``eval.results_dir``: ``config.yaml`` is the config
with the recording's sensor, ``inputs.json`` the fingerprints of the files it names), only after
every frame is replayed in memory: ``frames.jsonl`` (one line per frame, ``frame_record``),
``summary.json`` (``summarize``; also printed), ``map.npz`` (the agent's map after the last
frame, ``agent.navigator_map.AgentMap``) and, with ``--rerun``, ``replay.rrd``
(``agent.recording``: frames, camera, 3D and 2D maps, goals, actions on a ``step`` timeline).
"""
from __future__ import annotations

import math
import shutil
import tempfile
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

from calnav.eval.config import Config, ConfigError, agent_setup
from calnav.eval.results_dir import ResultsDir, writing
from dataclasses import dataclass
from calnav.eval.arguments import REQUIRED, Command, arg
from calnav.eval.config import EPISODE_SECTIONS
from calnav.mapping.registry import LAYOUTS
from calnav.eval.shorthands import fixed

DEFAULT_CONFIG = "configs/objectnav.yaml"
REPLAY_FILES: tuple[str, ...] = ("frames.jsonl", "summary.json", "map.npz", "replay.rrd")
FROM_RECORDING = ("env.resolution", "env.hfov_deg")   # set from the recording's depth camera
DECIMALS = 4               # metres and probabilities in the records: 0.1 mm, far below a 5 cm map cell
MIN_DETECTION_FRACTION = 0.01   # a class is listed among a frame's detections from 1 % of its pixels
PINHOLE_TOLERANCE_PX = 1.0      # the recording's K may differ this much from the agent's pinhole model
HEIGHT_TOLERANCE_M = 0.1        # a first camera z this far from env.camera_height_m gets a note
HFOV_DECIMALS = 9          # hfov from fx, rounded: 79.00000000000001 reads back as the 79 that made fx


def replay_configs(args) -> list[Config]:
    """The config ``calnav replay`` runs (sections env, mapping, run, agent, segmenter, sequence).
    The recording sets the sensor keys (``FROM_RECORDING``): an override of one is refused."""
    from calnav.eval.shorthands import load_command_config

    for text in args.overrides:
        key = text.partition("=")[0].strip()
        if key in FROM_RECORDING:
            raise ConfigError(f"calnav replay sets {key} from the recording's depth camera itself; remove the "
                              f"override {text}")
    return [load_command_config(args, config=args.config or DEFAULT_CONFIG)]


def sensor_config(cfg: Config, seq) -> tuple[Config, list[str]]:
    """``cfg`` with the agent's sensor model set to ``seq``'s depth camera (module docstring),
    and notes on what the model does not capture: a K other than a centred square pinhole."""
    w, h = seq.depth_size
    k = np.asarray(seq.k_depth, np.float64)
    hfov = round(math.degrees(2 * math.atan(w / 2 / k[0, 0])), HFOV_DECIMALS)
    try:
        env = replace(cfg.env, resolution=(int(w), int(h)), hfov_deg=hfov)
    except ValueError as exc:
        raise ValueError(f"{seq.root}: the recording's depth camera ({w}x{h}, fx {k[0, 0]:g}): {exc}") from None
    from calnav.envs.task import pinhole_intrinsics

    model = pinhole_intrinsics(w, h, hfov)
    off = float(np.abs(k[:2, :3] - model[:2, :3]).max())
    notes = []
    if off > PINHOLE_TOLERANCE_PX:
        notes.append(f"the recording's depth camera (fx {k[0, 0]:.1f}, fy {k[1, 1]:.1f}, cx {k[0, 2]:.1f}, cy "
                     f"{k[1, 2]:.1f}) differs from the agent's pinhole model (f {model[0, 0]:.1f}, cx {model[0, 2]:.1f}, "
                     f"cy {model[1, 2]:.1f}) by up to {off:.1f} px: the agent maps with its model")
    return replace(cfg, env=env), notes


def frame_record(index: int, decision, frame, class_names, goal_name: str) -> dict:
    """One line of ``frames.jsonl``: the recording's ``frame`` number, the agent's ``step``,
    ``action`` (name) / ``action_id``, ``mode``; in the episode-start frame (x forward at the
    first frame, y left; metres, rad): its pose ``x``, ``y``, ``yaw``, the ``long_term_goal`` and
    ``short_term_goal`` [x, y] (null when none), the map's ``goal`` component it heads for
    (accepted, peak confidence, area_m2, centre [x, y]) or null; the frame's own ``detections``
    (each class that is the arg-max of at least ``MIN_DETECTION_FRACTION`` of the pixels: its
    pixel ``fraction`` and mean ``confidence``, the segmenter's softmax) and
    ``goal_frame_confidence``, the highest probability of the goal class in the frame."""
    from calnav.agent.segmenters import softmax

    def xy(p):
        return None if p is None else [_round(p[0]), _round(p[1])]

    probs = softmax(frame.logits).reshape(-1, len(class_names))
    labels = probs.argmax(axis=1)
    top = probs[np.arange(len(labels)), labels]
    counts = np.bincount(labels, minlength=len(class_names))
    detections = [{"class": class_names[c], "fraction": round(float(counts[c] / len(labels)), DECIMALS),
                   "confidence": round(float(top[labels == c].mean()), DECIMALS)}
                  for c in np.argsort(-counts, kind="stable") if counts[c] >= MIN_DETECTION_FRACTION * len(labels)]
    g = decision.goal
    goal = None if g is None else {"accepted": g.accepted, "peak": round(g.peak, DECIMALS),
                                   "area_m2": round(g.area_m2, DECIMALS), "centre": xy(g.centre)}
    return {"frame": int(index), "step": decision.step, "action": decision.action.name,
            "action_id": int(decision.action), "mode": decision.mode, "x": _round(decision.position[0]),
            "y": _round(decision.position[1]), "yaw": _round(decision.yaw),
            "long_term_goal": xy(decision.long_term_goal), "short_term_goal": xy(decision.short_term_goal),
            "goal": goal, "detections": detections,
            "goal_frame_confidence": round(float(probs[:, class_names.index(goal_name)].max()), DECIMALS)}


def _round(value: float) -> float:
    return round(float(value), DECIMALS) + 0.0   # (+ 0.0: no -0.0 in the records)


def summarize(records: list[dict]) -> dict:
    """The replay in numbers: frames, actions by name, the frames the agent would STOP at (the
    first with its position), the first frame whose map holds an accepted goal (with its peak
    confidence), and how many times the long-term goal changed."""
    stops = [r for r in records if r["action"] == "STOP"]
    seen = next((r for r in records if r["goal"] is not None and r["goal"]["accepted"]), None)
    goals = [tuple(r["long_term_goal"]) for r in records if r["long_term_goal"] is not None]
    return {"frames": len(records), "actions": dict(Counter(r["action"] for r in records)),
            "stop_frames": [r["frame"] for r in stops],
            "first_stop": None if not stops else {k: stops[0][k] for k in ("frame", "x", "y", "yaw")},
            "goal_first_accepted": None if seen is None else {"frame": seen["frame"], "peak": seen["goal"]["peak"]},
            "long_term_goal_changes": sum(1 for a, b in zip(goals, goals[1:]) if a != b)}


def replay(seq, nav, goal: str, recording=None, progress: bool = True) -> tuple[list[dict], list[float]]:
    """Every frame of ``seq`` through ``nav`` (reset on ``goal``): the frame records and the
    camera z (metres) of each frame. ``recording``: an ``agent.recording.EpisodeRecording``."""
    from tqdm import tqdm

    from calnav.mapping.sequences import Registration

    reg = Registration(seq.k_color, seq.color_size, seq.k_depth, seq.depth_size)
    nav.reset(goal)
    records, heights = [], []
    for fr in tqdm(seq.frames(), total=len(seq), desc="replay", unit="frame", disable=not progress):
        semantic = reg.labels(fr.semantic) if nav.needs_semantic and fr.semantic is not None else None
        try:
            decision = nav.act(reg.rgb(fr.rgb), fr.depth, pose=fr.pose, semantic=semantic)
        except (ValueError, KeyError) as exc:   # a tilted pose, a frame without labels: one line naming it
            message = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc   # (a KeyError's str is quoted)
            raise ValueError(f"frame {fr.index}: {message}") from None
        records.append(frame_record(fr.index, decision, nav.frame, nav.class_names, nav.goal))
        heights.append(float(fr.pose[2, 3]))
        if recording is not None:
            recording.step(decision.agent_step, int(decision.action), {})
    return records, heights


def main_replay(args, configs: list[Config]) -> None:
    """``configs``: ``replay_configs(args)``, checked by the preflight. Everything is read and
    checked (recording, goal, output directory) before anything is written."""
    from calnav.agent.navigator import Navigator
    from calnav.mapping.sequences import Sequence

    if args.rerun:
        from calnav.common.rerun_io import require_rerun

        require_rerun("--rerun")   # the install command, before anything is read or written
    seq = Sequence(args.recording, args.layout, configs[0].sequence)
    cfg, notes = sensor_config(configs[0], seq)
    seq.check_scale(cfg.mapping.depth_min_m, cfg.mapping.depth_max_m, cfg.mapping.voxel_size_m)   # units, frame
    nav = Navigator(agent_setup(cfg))
    goal = int(args.goal) if args.goal.isdigit() else args.goal   # a name, or its id
    nav.goal_id(goal)   # an unknown goal: one line naming the valid ones
    if nav.needs_semantic and not seq.has_semantic:
        raise ValueError(f"agent.segmenter={cfg.agent.segmenter} reads ground-truth semantic frames, which {seq.root} "
                         "does not hold (sequence.rosbag.semantic_topic, or semantic/N.png); use --segmenter "
                         "learned_rgb or another learned segmenter")
    out = Path(args.output)
    results = ResultsDir(out, cfg, force=args.force, discard=REPLAY_FILES, files=REPLAY_FILES)
    results.check()   # refused now rather than after the replay, and nothing written yet
    with tempfile.TemporaryDirectory(prefix="calnav-replay-") as tmp:
        recording = None
        if args.rerun:
            from calnav.agent.recording import EpisodeRecording

            # (the recording's name: Rerun's application ids take no dots, so not the file's name)
            recording = EpisodeRecording(Path(tmp) / "replay.rrd", nav.class_names, f"replay {goal}")
        t0 = time.perf_counter()
        records, heights = replay(seq, nav, goal, recording)
        seconds = time.perf_counter() - t0
        if abs(float(np.median(heights)) - cfg.env.camera_height_m) > HEIGHT_TOLERANCE_M:
            notes.append(f"the recording's camera is at z {np.median(heights):.2f} m (median); the agent assumes "
                         f"env.camera_height_m = {cfg.env.camera_height_m:g} m above the floor: set it if the "
                         "recording's z = 0 is the floor")
        summary = {"recording": str(seq.root), "layout": seq.layout, "goal": nav.goal,
                   **summarize(records), "skipped_frames": list(seq.skipped), "skip_reasons": seq.skips.by_reason(),
                   "skipped_why": seq.skip_summary(),
                   "seconds": round(seconds, 3), "frames_per_s": round(len(records) / max(seconds, 1e-9), 3),
                   "sensor": {"resolution": list(cfg.env.resolution), "hfov_deg": cfg.env.hfov_deg},
                   "notes": notes}
        with results:
            for name in REPLAY_FILES:
                (out / name).unlink(missing_ok=True)
            with writing(out):
                _write(results, out, records, summary, nav, recording)
    _print(summary, out, recording is not None)


def _write(results: ResultsDir, out: Path, records: list[dict], summary: dict, nav, recording) -> None:
    from calnav.common.atomic import json_text

    nav.save_map(out / "map.npz")
    if recording is not None:
        shutil.move(str(recording.close()), out / "replay.rrd")
    lines = (json_text(r, None, what=str(out / "frames.jsonl")) + "\n" for r in records)
    results.write_text("frames.jsonl", "".join(lines))
    results.write_json("summary.json", summary)


def _print(summary: dict, out: Path, rerun: bool) -> None:
    s = summary
    skipped = f" ({len(s['skipped_frames'])} skipped: {s['skipped_why']})" if s["skipped_frames"] else ""
    print(f"{s['recording']}: {s['frames']} frames replayed{skipped}, goal {s['goal']}, {s['frames_per_s']:.1f} frames/s")
    print("actions: " + ", ".join(f"{name} {n}" for name, n in sorted(s["actions"].items(), key=lambda kv: -kv[1])))
    seen, stop = s["goal_first_accepted"], s["first_stop"]
    print(f"goal accepted on the map from frame {seen['frame']} (peak confidence {seen['peak']:.3f})" if seen
          else "the goal is never accepted on the map")
    print(f"the agent would STOP at frame {stop['frame']} (x {stop['x']:.2f}, y {stop['y']:.2f} m from the first frame; "
          f"{len(s['stop_frames'])} STOP frames)" if stop else "the agent would not STOP")
    for note in s["notes"]:
        print(f"note: {note}")
    print(f"wrote {out / 'frames.jsonl'}, {out / 'summary.json'}, {out / 'map.npz'}"
          + (f", {out / 'replay.rrd'} (calnav view {out / 'replay.rrd'})" if rerun else ""))


@dataclass
class ReplayArgs:
    """``calnav replay``'s flags."""

    recording: str = arg(REQUIRED, "a ROS bag (--layout rosbag, the default) or a recording's directory",
                         positional=True)
    goal: str = arg(REQUIRED, "the goal category searched (name or id: chair, bed, plant, ...)")
    layout: str = arg("rosbag", "file layout of the recording", choices=LAYOUTS.names())
    segmenter: str | None = arg(None, "shorthand for agent.segmenter (default learned_rgb: a recording has no "
                                      "ground-truth labels)", metavar="SEGMENTER", sets="agent.segmenter",
                                sets_default="learned_rgb")
    output: str = arg(REQUIRED, "results directory")
    force: bool = arg(False, "replace the results of another config in --output")
    rerun: bool = arg(False, "also write <output>/replay.rrd (Rerun: frames, camera, maps, goals; needs the [viz] "
                             "extra)")


COMMAND = Command(ReplayArgs, main_replay, replay_configs, config="",
                  config_help="YAML config of the agent (default: configs/objectnav.yaml)",
                  overrides="dotted config overrides, e.g. agent.goal_threshold=0.9 sequence.frame_stride=2",
                  checks=("run", "agent", "mapping"),   # the agent's segmenter and files; no study
                  sections=(*EPISODE_SECTIONS, "sequence"),
                  fixed=(fixed("env.normalize_depth", "false"),))   # the recording's depth is metres
