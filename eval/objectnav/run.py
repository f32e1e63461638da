"""`calnav objectnav`: run the configured agent (``run.agent``) on a split's episodes, in
parallel workers, resumably.

Output directory: ``config.yaml`` (the resolved config), ``episodes.jsonl`` (one line per
finished episode, appended and flushed as each finishes, so a killed run loses at most the
episodes in flight), ``summary.json`` (mean and SEM of Success, SPL, SoftSPL, DistanceToGoal,
per-category breakdown), ``plots/*.png`` (``eval.objectnav.report.plot_run``) and, with
``--video N``, ``videos/<episode_id>.mp4`` (":" -> "_") for the first N episodes of the range (drawn in the
worker that runs the episode; agents with a map only). Rerunning into the same directory skips
finished episodes; a directory holding a different config is refused unless ``--force``.
``-m/--multirun`` runs the cross product of comma-separated overrides, one subdirectory each,
and writes ``comparison.md`` / ``.csv`` / ``.png`` (``eval.objectnav.report``).
"""
from __future__ import annotations

import json
import multiprocessing as mp
import os
import re
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from eval.config import Config, ConfigError, build_dataclass, dump_yaml, load_config, to_dict
from eval.preflight import check_command
from eval.stats import format_metrics_table, summarize

# Dotted config keys that do not change results: a rerun with other values may resume the same
# directory, and `calnav compare` never makes them columns.
RESULT_NEUTRAL_KEYS: tuple[str, ...] = ("run.workers", "run.output_dir")

_worker_state: dict = {}

# Agents that ``render_panel`` can draw (it needs a semantic map, a frame and step info).
VIDEO_AGENTS = ("peanut",)


def _neutral(cfg_dict: dict) -> dict:
    out = json.loads(json.dumps(cfg_dict))
    for dotted in RESULT_NEUTRAL_KEYS:
        section, key = dotted.split(".")
        out.get(section, {}).pop(key, None)
    return out


def run_one_episode(env, agent, index: int, video_dir: Path | None = None) -> dict:
    """Run episode ``index`` to the end; returns its result record. With ``video_dir``, one
    ``render_panel`` per step goes to ``video_dir/<episode_id>.mp4`` (read-only on the agent:
    the actions, hence the metrics, are the same as without)."""
    t0 = time.perf_counter()
    obs, info = env.reset(options={"episode_index": index})
    agent.reset(obs)
    video = None
    if video_dir is not None:
        from agent.visualize import EpisodeVideo, render_panel

        name = re.sub(r"[^\w.-]", "_", env.unwrapped.episode.episode_id)  # ':' is not portable
        video = EpisodeVideo(Path(video_dir) / f"{name}.mp4")
    terminated = truncated = False
    while not (terminated or truncated):
        action = agent.act(obs)
        if video is not None:
            video.add(render_panel(agent))
        obs, _, terminated, truncated, info = env.step(action)
    ep = env.unwrapped.episode
    extra = {"video": str(video.write())} if video is not None and video.frames else {}
    return {**extra,
        "index": index, "episode_id": ep.episode_id, "scene": ep.scene_id, "category": ep.object_category,
        "success": info["success"], "spl": info["spl"], "softspl": info["softspl"],
        "distance_to_goal": info["distance_to_goal"], "geodesic_distance": ep.geodesic_distance,
        "steps": info["steps"], "path_length": info["path_length"], "collisions": info["collisions"],
        "stop_reason": "stop" if terminated else "max_steps",
        "wall_time_s": round(time.perf_counter() - t0, 3), "status": "ok",
    }


def _worker_init(cfg_dict: dict, agent_name: str, video_dir: str | None = None,
                 video_indices: tuple[int, ...] = ()) -> None:
    import gymnasium as gym

    import envs  # noqa: F401  (registers the env)
    from eval.objectnav.agents import make_agent

    cfg = build_dataclass(Config, cfg_dict)
    env = gym.make("calnav/ObjectNav-v0", split=cfg.env.split, config=cfg.env)
    _worker_state.update(env=env, agent=make_agent(agent_name, env, cfg), video_dir=video_dir,
                         video_indices=set(video_indices))


def _worker_run(index: int) -> dict:
    try:
        video = _worker_state["video_dir"] if index in _worker_state["video_indices"] else None
        return run_one_episode(_worker_state["env"], _worker_state["agent"], index, video)
    except Exception as exc:  # report the episode, keep the run going
        return {"index": index, "status": "error", "error": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc(limit=5)}


def load_records(path: Path) -> list[dict]:
    """Finished episode records; a torn last line (killed mid-write) is ignored."""
    if not path.exists():
        return []
    records = []
    for line in path.read_text().splitlines():
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return records


def repair_records(path: Path) -> None:
    """Drop a torn last line (a run killed mid-write) so appends start on a fresh line."""
    if not path.exists():
        return
    text = path.read_text()
    if text and not text.endswith("\n"):
        keep = text[: text.rfind("\n") + 1]
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(keep)
        tmp.replace(path)


def prepare_output(out: Path, cfg: Config, force: bool) -> None:
    out.mkdir(parents=True, exist_ok=True)
    cfg_path = out / "config.yaml"
    import yaml

    if cfg_path.exists():
        old = yaml.safe_load(cfg_path.read_text()) or {}
        if _neutral(old) != _neutral(to_dict(cfg)):
            if not force:
                raise ConfigError(f"{out} holds results of a different config ({cfg_path}); "
                                  "use another --output, or --force to discard them")
            (out / "episodes.jsonl").unlink(missing_ok=True)
    cfg_path.write_text(dump_yaml(cfg))


def run_objectnav(cfg: Config, indices: list[int], out: Path, force: bool = False,
                  progress: bool = True, video: int = 0, plots: bool = True) -> dict:
    """Run (or resume) ``indices`` of ``cfg.env.split`` with agent ``cfg.run.agent``; returns the
    summary dict. ``video``: write videos of the first ``video`` indices (those still to run);
    ``plots``: write plots/. The agent is part of the saved config, so resuming a directory
    with another agent is refused like any other config change."""
    from tqdm import tqdm

    agent_name = cfg.run.agent
    if video and agent_name not in VIDEO_AGENTS:
        raise ValueError(f"--video draws the agent's semantic map; agent {agent_name!r} has none "
                         f"(agents with videos: {', '.join(VIDEO_AGENTS)})")
    prepare_output(out, cfg, force)
    results_path = out / "episodes.jsonl"
    repair_records(results_path)
    done = {r["index"] for r in load_records(results_path) if "index" in r}
    todo = [i for i in indices if i not in done]
    workers = cfg.run.workers or os.cpu_count() or 1
    workers = max(1, min(workers, len(todo)))
    cfg_dict = to_dict(cfg)
    init_args = (cfg_dict, agent_name, str(out / "videos"), tuple(indices[:max(0, video)]))
    bar = tqdm(total=len(indices), initial=len(indices) - len(todo), disable=not progress,
               desc=f"objectnav[{agent_name}]", unit="ep")
    records = [r for r in load_records(results_path) if r.get("index") in set(indices)]

    def finish(rec: dict, f) -> None:
        f.write(json.dumps(rec) + "\n")
        f.flush()
        records.append(rec)
        s = summarize(records)
        bar.set_postfix(Success=f"{s['success']:.3f}", SPL=f"{s['spl']:.3f}")
        bar.update(1)
        if rec.get("status") != "ok":
            tqdm.write(f"episode {rec['index']} failed: {rec.get('error')}")

    with open(results_path, "a") as f:
        if workers == 1 and todo:
            _worker_init(*init_args)
            for i in todo:
                finish(_worker_run(i), f)
        elif todo:
            ctx = mp.get_context("spawn")  # Open3D's thread pools do not survive fork()
            with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_worker_init,
                                     initargs=init_args) as pool:
                for fut in as_completed([pool.submit(_worker_run, i) for i in todo]):
                    finish(fut.result(), f)
    bar.close()
    summary = summarize(records)
    summary["agent"] = agent_name
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    if plots and records:
        from eval.objectnav.report import plot_run

        plot_run(summary, out, title=agent_name)
    return summary


def agent_overrides(args, overrides: list[str]) -> list[str]:
    """``overrides`` plus ``run.agent=NAME`` when ``--agent NAME`` was given (its shorthand)."""
    agent = getattr(args, "agent", None)
    return [*overrides, f"run.agent={agent}"] if agent else list(overrides)


def _run_from_args(args, overrides: list[str], out: Path | None) -> tuple[dict, Path]:
    """Load the config with ``overrides`` (and --agent), resolve --episodes, run into ``out``
    (default: run.output_dir); returns (summary, output directory)."""
    from envs.episodes import load_split, parse_episode_range

    cfg = load_config(args.config, agent_overrides(args, overrides))
    episodes = load_split(cfg.env.split, cfg.env)
    indices = list(parse_episode_range(str(args.episodes), len(episodes)))
    out = Path(out or cfg.run.output_dir)
    summary = run_objectnav(cfg, indices, out, force=args.force, video=getattr(args, "video", 0))
    return summary, out


def main_objectnav(args) -> None:
    check_command(args, "objectnav")  # every file the configs name, before anything is written
    from eval.config import expand_multirun

    if getattr(args, "video", 0) < 0:
        raise ValueError(f"--video must be >= 0, got {args.video}")
    if not getattr(args, "multirun", False):
        summary, out = _run_from_args(args, args.overrides, args.output)
        print(format_metrics_table([(summary["agent"], summary)], first_header="Agent"))
        print(f"results: {out}/episodes.jsonl, {out}/summary.json, {out}/plots/")
        return
    from eval.objectnav.report import combo_dirname, combo_values, varied_keys, write_comparison

    combos = expand_multirun(list(args.overrides))
    keys = varied_keys(list(args.overrides))
    for combo in combos:  # validate every combination before running any
        load_config(args.config, agent_overrides(args, combo))
    root = Path(args.output or load_config(args.config, combos[0]).run.output_dir)
    rows = []
    for combo in combos:
        values = combo_values(combo, keys)
        print(f"== {combo_dirname(values)}")
        summary, _ = _run_from_args(args, combo, root / combo_dirname(values))
        rows.append((values, summary))
    table = write_comparison(keys, rows, root)
    print(table)
    print(f"results: {root}/<combination>/, {root}/comparison.md, {root}/comparison.csv, {root}/comparison.png")
