"""`calnav objectnav`: run the configured agent (``run.agent``) on a split's episodes, in
parallel workers, resumably.

Output directory: ``config.yaml`` (the resolved config), ``episodes.jsonl`` (one line per
finished episode, appended and flushed as each finishes, so a killed run loses at most the
episodes in flight), ``summary.json`` (mean and SEM of Success, SPL, SoftSPL, DistanceToGoal,
per-category breakdown), ``plots/*.png`` (``eval.objectnav.report.plot_run``) and, with
``--video N``, ``videos/<episode_id>.mp4`` (":" -> "_") for the first N episodes of the range (drawn in the
worker that runs the episode; agents with a map only). The directory is owned by
``eval.results_dir``: it is locked while a run writes it (a second run into it is refused), a
directory holding a different config is refused unless ``--force``, and rerunning into it skips
finished episodes, retries crashed ones and counts each episode once (``summary.json``'s
``duplicates`` says how many duplicate records were dropped). A run whose episodes all crash
raises ``AllEpisodesFailed`` (exit 2) with the first error, after writing its records and summary.
``-m/--multirun`` runs the cross product of comma-separated overrides, one subdirectory each,
and writes ``comparison.md`` / ``.csv`` / ``.png`` (``eval.objectnav.report``).
"""
from __future__ import annotations

import multiprocessing as mp
import os
import re
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from eval.config import Config, build_dataclass, load_config, to_dict
from eval.results_dir import RECORDS_NAME, AllEpisodesFailed, ResultsDir, writing
from eval.preflight import check_command
from eval.stats import format_metrics_table, summarize

# What --force deletes from a directory that holds another config's results.
RUN_RESULTS: tuple[str, ...] = (RECORDS_NAME, "summary.json", "plots", "videos")

_worker_state: dict = {}

# Agents that ``render_panel`` can draw (it needs a semantic map, a frame and step info).
VIDEO_AGENTS = ("peanut",)


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


def crashed(record: dict) -> bool:
    """A record to retry on resume: the episode crashed (``status != "ok"``)."""
    return record.get("status", "ok") != "ok"


def check_not_all_failed(records: list[dict]) -> None:
    """Raise AllEpisodesFailed (with the first error) when every one of ``records`` crashed: a
    table of zeros from a broken setup (e.g. an unreadable ``mapping.glfs_params``) must not
    look like a result."""
    if records and all(crashed(r) for r in records):
        first = min(records, key=lambda r: r["index"])
        raise AllEpisodesFailed(f"all {len(records)} episodes failed; first error (episode {first['index']}): "
                                f"{first.get('error', 'unknown error')}")


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
    with ResultsDir(out, cfg, force=force, discard=RUN_RESULTS) as results:
        records_file = results.records()
        # crashed episodes of this range are dropped from the file, so they run again
        resumed = records_file.resume(retry=crashed, indices=indices)
        wanted = set(indices)
        records = {i: r for i, r in resumed.records.items() if i in wanted}
        todo = [i for i in indices if i not in records]
        workers = cfg.run.workers or os.cpu_count() or 1
        workers = max(1, min(workers, len(todo)))
        init_args = (to_dict(cfg), agent_name, str(out / "videos"), tuple(indices[:max(0, video)]))
        bar = tqdm(total=len(indices), initial=len(indices) - len(todo), disable=not progress,
                   desc=f"objectnav[{agent_name}]", unit="ep")

        def finish(rec: dict) -> None:
            records_file.append(rec)
            records[rec["index"]] = rec
            s = summarize(list(records.values()))
            bar.set_postfix(Success=f"{s['success']:.3f}", SPL=f"{s['spl']:.3f}")
            bar.update(1)
            if crashed(rec):
                tqdm.write(f"episode {rec['index']} failed: {rec.get('error')}")

        with records_file:
            if workers == 1 and todo:
                _worker_init(*init_args)
                for i in todo:
                    finish(_worker_run(i))
            elif todo:
                ctx = mp.get_context("spawn")  # Open3D's thread pools do not survive fork()
                with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_worker_init,
                                         initargs=init_args) as pool:
                    for fut in as_completed([pool.submit(_worker_run, i) for i in todo]):
                        finish(fut.result())
        bar.close()
        ordered = [records[i] for i in indices if i in records]
        summary = summarize(ordered)
        summary["agent"] = agent_name
        summary["duplicates"] = resumed.duplicates  # found (and dropped) in the records file
        results.write_json("summary.json", summary)
        if plots and ordered:
            from eval.objectnav.report import plot_run

            with writing(out / "plots"):
                plot_run(summary, out, title=agent_name)
    check_not_all_failed(ordered)
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
    with ResultsDir(root, files=()):  # one multirun per root: its comparison covers its own runs
        for combo in combos:
            values = combo_values(combo, keys)
            print(f"== {combo_dirname(values)}")
            summary, _ = _run_from_args(args, combo, root / combo_dirname(values))
            rows.append((values, summary))
        with writing(root / "comparison.md"):
            table = write_comparison(keys, rows, root)
    print(table)
    print(f"results: {root}/<combination>/, {root}/comparison.md, {root}/comparison.csv, {root}/comparison.png")
