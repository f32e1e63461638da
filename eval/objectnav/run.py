"""`calnav objectnav`: run the configured agent (``run.agent``) on a split's episodes, in
parallel workers, resumably.

Output directory: ``config.yaml`` (the resolved config), ``episodes.jsonl`` (one line per
finished episode, appended and flushed as each finishes, so a killed run loses at most the
episodes in flight), ``summary.json`` (mean and SEM of Success, SPL, SoftSPL, DistanceToGoal,
per-category breakdown), ``plots/*.png`` (``eval.objectnav.report.plot_run``) and, with
``--video N``, ``videos/<episode_id>.mp4`` (":" -> "_") for the first N episodes of the range (drawn in the
worker that runs the episode; agents with a map only); with ``--rerun N``, ``rerun/<episode_id>.rrd``
likewise (``agent.recording``: camera, frames, segmentation, the 3D and 2D maps, metrics on a
``step`` timeline; the ``[viz]`` extra). The directory is owned by
``eval.results_dir``: it is locked while a run writes it (a second run into it is refused), a
directory holding a different config is refused unless ``--force``, and rerunning into it skips
finished episodes, retries crashed ones and counts each episode once (``summary.json``'s
``duplicates`` says how many duplicate records were dropped). A run whose episodes all crash
raises ``AllEpisodesFailed`` (exit 2) with the first error, after writing its records and summary.
``-m/--multirun`` runs the cross product of comma-separated overrides, one subdirectory each,
and writes ``comparison.md`` / ``.csv`` / ``.png`` (``eval.objectnav.report``).
"""
from __future__ import annotations

import json
import time
from contextlib import ExitStack
from functools import partial
from dataclasses import dataclass, field
from pathlib import Path

from calnav.common.provenance import running_commit
from calnav.agent.setup import AgentSetup
from calnav.eval.config import Config, agent_setup, to_dict
from calnav.eval.results_dir import EPISODE_NEUTRAL_KEYS, RECORDS_NAME, AllEpisodesFailed, ResultsDir, writing
from calnav.eval.stats import failure_modes, finite_or_error, format_metrics_table, run_label, summarize
from calnav.common.ranges import Range
from calnav.eval.arguments import Command, arg

# What --force deletes from a directory that holds another config's results.
RUN_RESULTS: tuple[str, ...] = (RECORDS_NAME, "summary.json", "plots", "videos", "rerun")

_worker_state: dict = {}

# Agents that ``render_panel`` can draw (it needs a semantic map, a frame and step info).
VIDEO_AGENTS = ("peanut",)


def run_one_episode(env, agent, index: int, video_dir: Path | None = None, rerun_dir: Path | None = None) -> dict:
    """Run episode ``index`` to the end (``eval.rollout``); returns its result record. With
    ``video_dir``, one ``render_panel`` per step goes to ``video_dir/<episode_id>.mp4``; with
    ``rerun_dir``, the episode is recorded to ``rerun_dir/<episode_id>.rrd`` (``agent.recording``).
    Both are read-only hooks: the actions, hence the metrics, are the same as without."""
    from calnav.eval.objectnav.hooks import RerunHook, VideoHook
    from calnav.eval.rollout import rollout

    t0 = time.perf_counter()
    video = VideoHook(video_dir) if video_dir is not None else None
    recording = RerunHook(rerun_dir) if rerun_dir is not None else None
    result = rollout(env, agent, index, [h for h in (video, recording) if h is not None])
    ep, info = env.unwrapped.episode, result.info
    extra = {"video": str(video.path)} if video is not None and video.path is not None else {}
    if env.unwrapped.config.dataset.storeys > 1 or env.unwrapped.navgrid.layered:   # (one storey: records as before)
        extra.update(start_storey=int(ep.start_storey), goal_storey=int(ep.goal_storey))
    if recording is not None:
        extra["rerun"] = str(recording.path)
    return finite_or_error({**extra,   # a non-finite metric makes it an error record (eval.stats)
        "index": index, "episode_id": ep.episode_id, "scene": ep.scene_id, "category": ep.object_category,
        "success": info["success"], "spl": info["spl"], "softspl": info["softspl"],
        "distance_to_goal": info["distance_to_goal"], "geodesic_distance": ep.geodesic_distance,
        "steps": info["steps"], "path_length": info["path_length"], "collisions": info["collisions"],
        "steps_at_goal": int(info["steps_at_goal"]),
        "stop_reason": "stop" if result.terminated else "max_steps",
        "wall_time_s": round(time.perf_counter() - t0, 3), "status": "ok", "commit": running_commit(),
    })


@dataclass
class EpisodeTask:
    """One episode to run: the job's config (validated once, where it was loaded: it pickles to
    the worker as it is) for its env, its agent's setup (``eval.config.agent_setup``), the
    episode index within the split, and the video / Rerun directory if this episode gets one."""

    job: int
    cfg: Config
    setup: AgentSetup
    index: int
    video_dir: str | None = None
    rerun_dir: str | None = None
    env_maker: str = ""           # EpisodeJob.env_maker
    env_args: dict = field(default_factory=dict)
    upto: int | None = None       # the job's episodes lie in 0:upto (the env loads those scenes only)


def _make_env(cfg: Config, env_maker: str, env_args: dict, upto: int | None = None):
    """The job's gym env: calnav's ObjectNav env of ``cfg.env`` holding the split's episodes
    ``0:upto`` (their scenes only: a worker never generates a scene the run does not need), or
    ``env_maker(cfg, **env_args)``."""
    import gymnasium as gym

    import calnav.envs  # noqa: F401  (registers the env)
    from calnav.envs.episodes import load_split

    if not env_maker:
        episodes = load_split(cfg.env.split, cfg.env, progress=False, upto=upto)
        return gym.make("calnav/ObjectNav-v0", split=cfg.env.split, config=cfg.env, episodes=episodes)
    import importlib

    module, _, function = env_maker.partition(":")
    return getattr(importlib.import_module(module), function)(cfg, **env_args)


def _warm_env_agent(cfg: Config, setup: AgentSetup, env_maker: str = "", env_args: dict | None = None,
                    upto: int | None = None):
    """This process's env and agent for a config, built once and reused while tasks keep the
    same config (a pool or Ray worker stays warm, as an episode loop would). The agent is the
    library's ``agent.navigator.Navigator`` of ``setup`` (handed the env's privileged
    ``simulator_handle`` only if its class declares it: the oracle), run by the episode loop as
    an ``EpisodeAgent``."""
    from calnav.agent.navigator import EpisodeAgent, Navigator

    key = (json.dumps([to_dict(cfg), env_maker, env_args or {}, upto], sort_keys=True), setup)
    if _worker_state.get("key") != key:
        if "env" in _worker_state:
            _worker_state["env"].close()
        _worker_state.clear()
        env = _make_env(cfg, env_maker, env_args or {}, upto)
        agent = EpisodeAgent(Navigator(setup, simulator=env.unwrapped.simulator_handle()))
        _worker_state.update(key=key, env=env, agent=agent)
    return _worker_state["env"], _worker_state["agent"]


def run_episode_task(task: EpisodeTask) -> dict:
    """Run one task in this process (any backend); a crash is raised to ``eval.runner.run_tasks``,
    which hands it back as an error record (``error_record``) so the run keeps going."""
    from calnav.eval.backends import ray_node_id

    env, agent = _warm_env_agent(task.cfg, task.setup, task.env_maker, task.env_args, task.upto)
    record = run_one_episode(env, agent, task.index, task.video_dir, task.rerun_dir)
    node = ray_node_id()
    if node is not None:
        record["ray_node"] = node  # where it ran (run.backend=ray); metrics ignore it
    return record


def error_record(task: EpisodeTask, failure) -> dict:
    """The record of an episode whose task raised (``eval.runner.TaskFailed``): retried on resume."""
    return {"index": task.index, "status": "error", "error": failure.error,
            "traceback": "\n".join(failure.traceback.splitlines()[-12:]), "commit": running_commit()}


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


@dataclass
class EpisodeJob:
    """One results directory: a config, the episode indices it should hold, where it goes, and
    how many of its first episodes get a video / a Rerun recording."""

    cfg: Config
    indices: list[int]
    out: Path
    video: int = 0
    rerun: int = 0
    # "module:function" building the env as function(cfg, **env_args) (JSON-serialisable arguments:
    # they key the worker's warm env), for
    # a study that changes the world around the same config (the start-pose study's frames and
    # rotated houses); "" = calnav's ObjectNav env of cfg.env
    env_maker: str = ""
    env_args: dict = field(default_factory=dict)


def run_objectnav(cfg: Config, indices: list[int], out: Path, force: bool = False,
                  progress: bool = True, video: int = 0, plots: bool = True) -> dict:
    """Run (or resume) ``indices`` of ``cfg.env.split`` with agent ``cfg.run.agent``; returns the
    summary dict. ``video``: write videos of the first ``video`` indices (those still to run);
    ``plots``: write plots/. The agent is part of the saved config, so resuming a directory
    with another agent is refused like any other config change."""
    return run_jobs([EpisodeJob(cfg, list(indices), Path(out), video)], force, progress, plots)[0]


def run_jobs(jobs: list[EpisodeJob], force: bool = False, progress: bool = True, plots: bool = True) -> list[dict]:
    """Run (or resume) several results directories at once: every job's missing episodes are
    submitted together to the backend of the jobs' ``run`` section (``run.backend``; all jobs
    must share it), so a multirun or a tuning grid keeps every worker busy. Each record is
    appended to its own job's ``episodes.jsonl`` as it arrives; returns the jobs' summaries
    (also written as ``summary.json``), in job order. Raises ``AllEpisodesFailed`` when every
    episode of a job crashed (after all records and summaries are written)."""
    from tqdm import tqdm

    from calnav.eval.backends import check_backend
    from calnav.eval.runner import run_tasks

    run_cfg = jobs[0].cfg.run
    for job in jobs:  # every check before anything is written
        if (job.cfg.run.backend, job.cfg.run.ray_address) != (run_cfg.backend, run_cfg.ray_address):
            raise ValueError("run.backend / run.ray_address must be the same for every configuration of one run")
        for option, n in (("--video", job.video), ("--rerun", job.rerun)):
            if n and job.cfg.run.agent not in VIDEO_AGENTS:
                raise ValueError(f"{option} draws the agent's semantic map; agent {job.cfg.run.agent!r} has none "
                                 f"(agents with one: {', '.join(VIDEO_AGENTS)})")
        if job.rerun:
            from calnav.common.rerun_io import require_rerun

            require_rerun("--rerun")   # the install command, before anything is written
    check_backend(run_cfg.backend, run_cfg.ray_address)   # before anything is written
    from calnav.eval.episodes import check_file_scenes, other_recorded_episodes, refused_episodes

    for job in jobs:
        check_file_scenes(job.cfg, job.indices)   # a scene without what the agent reads: before anything is written

    refusals = [refused_episodes(job.cfg.env, job.indices) for job in jobs]   # an episode file's, on calnav's navmesh
    for job, refused in zip(jobs, refusals):
        if refused and len(refused) == len(job.indices):
            raise ValueError(f"every episode of {job.out}'s range is refused on calnav's navmesh; the first, "
                             f"{min(refused)}: {refused[min(refused)]}")
    with ExitStack() as stack:
        dirs, files, records, duplicates, tasks = [], [], [], [], []
        for j, (job, refused) in enumerate(zip(jobs, refusals)):
            results = stack.enter_context(ResultsDir(
                job.out, job.cfg, force=force, discard=RUN_RESULTS, neutral_keys=EPISODE_NEUTRAL_KEYS,
                other_records=partial(other_recorded_episodes, job.cfg.env, indices=job.indices)))
            records_file = results.records()
            # crashed episodes of this range are dropped from the file, so they run again
            resumed = records_file.resume(retry=crashed, indices=job.indices)
            wanted = set(job.indices) - set(refused)
            done = {i: r for i, r in resumed.records.items() if i in wanted}
            dirs.append(results)
            files.append(stack.enter_context(records_file))
            records.append(done)
            duplicates.append(resumed.duplicates)
            setup, videos = agent_setup(job.cfg), set(job.indices[:max(0, job.video)])
            recorded = set(job.indices[:max(0, job.rerun)])
            tasks += feed_order([EpisodeTask(j, job.cfg, setup, i,
                                             str(job.out / "videos") if i in videos else None,
                                             str(job.out / "rerun") if i in recorded else None, job.env_maker,
                                             job.env_args, max(job.indices) + 1)
                              for i in job.indices if i not in done and i not in refused], job.cfg)
        total = sum(len(job.indices) - len(refused) for job, refused in zip(jobs, refusals))
        for job, refused in zip(jobs, refusals):
            if refused and progress:
                tqdm.write(f"{job.out}: {len(refused)} of {len(job.indices)} episodes refused on calnav's navmesh "
                           f"(not run; summary.json lists them): {refusal_counts(refused)}")
        name = jobs[0].cfg.run.agent if len(jobs) == 1 else f"{len(jobs)} configs"
        if progress and not tasks:   # a rerun of a finished range: say so, rather than a bare 100% bar
            tqdm.write(f"nothing to run: all {total} episodes are recorded in "
                       f"{', '.join(str(job.out) for job in jobs)} (the figures below are theirs)")

        def save(task: EpisodeTask, rec: dict) -> None:
            files[task.job].append(rec)
            records[task.job][rec["index"]] = rec
            if crashed(rec):
                tqdm.write(f"{jobs[task.job].out}: episode {rec['index']} failed: {rec.get('error')}")

        def postfix(task: EpisodeTask) -> dict:   # the running figures of the finished episode's job
            s = summarize(list(records[task.job].values()))
            return {"Success": f"{s['success']:.3f}", "SPL": f"{s['spl']:.3f}"}

        run_tasks(run_episode_task, tasks, run_cfg, save=save, failed=lambda t, f: save(t, error_record(t, f)),
                  desc=f"objectnav[{name}]", unit="ep", total=total, progress=progress, postfix=postfix)
        summaries, ordered_all = [], []
        for job, results, recs, dup, refused in zip(jobs, dirs, records, duplicates, refusals):
            ordered = [recs[i] for i in job.indices if i in recs]
            summary = summarize(ordered)
            if refused:   # an episode file's episodes calnav cannot run: counted, never averaged in
                summary["refused"] = {"episodes": len(refused), "by_reason": refusal_counts(refused),
                                      "by_scene": refusal_counts(refused, by_scene=True),
                                      "indices": {str(i): why for i, why in sorted(refused.items())}}
            summary["failures"] = failure_modes(ordered, job.cfg.env.max_episode_steps)
            summary["agent"] = job.cfg.run.agent
            summary["duplicates"] = dup  # found (and dropped) in the records file
            results.write_json("summary.json", summary)
            if plots and ordered:
                from calnav.eval.objectnav.report import plot_run

                with writing(job.out / "plots"):
                    plot_run(summary, job.out, title=job.cfg.run.agent)
            summaries.append(summary)
            ordered_all.append(ordered)
    for ordered in ordered_all:
        check_not_all_failed(ordered)
    return summaries


def refusal_counts(refused: dict[int, str], by_scene: bool = False) -> dict[str, int]:
    """{reason kind (the text before its colon): episodes} of ``refused`` ({index: "<scene>:
    <reason>"}), or {scene: episodes} with ``by_scene``."""
    out: dict[str, int] = {}
    for text in refused.values():
        scene, _, why = text.partition(": ")
        kind = scene if by_scene else why.split(":")[0]
        out[kind] = out.get(kind, 0) + 1
    return dict(sorted(out.items()))


def feed_order(tasks: list[EpisodeTask], cfg: Config) -> list[EpisodeTask]:
    """One job's tasks in the order the pool takes them: houses as they come (a worker keeps its
    house loaded while the next episode is in it) and, within each house, the longest geodesic
    first, so the last episodes of a run are its shortest and no worker waits long for the
    others at the end. Order only: each episode's record is the same whatever runs before it."""
    from calnav.envs.episodes import load_split

    episodes = load_split(cfg.env.split, cfg.env, upto=max(t.index for t in tasks) + 1) if tasks else []
    houses: dict[str, int] = {}
    for t in tasks:
        houses.setdefault(episodes[t.index].scene_id, len(houses))
    return sorted(tasks, key=lambda t: (houses[episodes[t.index].scene_id], -episodes[t.index].geodesic_distance,
                                        t.index))


def objectnav_configs(args) -> list[Config]:
    """Every config ``calnav objectnav`` runs for ``args``: the one, or each multirun combination
    of comma-separated overrides in order (with the command's shorthands: ``--agent NAME`` is
    ``run.agent=NAME``)."""
    from calnav.eval.config import expand_multirun
    from calnav.eval.shorthands import load_command_config

    for option in ("video", "rerun"):
        if getattr(args, option, 0) < 0:
            raise ValueError(f"--{option} must be >= 0, got {getattr(args, option)}")
    if getattr(args, "rerun", 0):
        from calnav.common.rerun_io import require_rerun

        require_rerun("--rerun")
    combos = expand_multirun(list(args.overrides)) if getattr(args, "multirun", False) else [list(args.overrides)]
    return [load_command_config(args, combo) for combo in combos]


def _job(args, cfg: Config, out: Path | None) -> EpisodeJob:
    """``cfg``'s job: --episodes resolved on its split, writing to ``out`` (default: run.output_dir)."""
    from calnav.eval.episodes import episode_indices

    indices = list(episode_indices(str(args.episodes), cfg.env, cfg.run))
    return EpisodeJob(cfg, indices, Path(out or cfg.run.output_dir), getattr(args, "video", 0), getattr(args, "rerun", 0))


def main_objectnav(args, configs: list[Config]) -> None:
    """``configs``: ``objectnav_configs(args)``, checked by the preflight."""
    if not getattr(args, "multirun", False):
        job = _job(args, configs[0], args.output)
        summary = run_jobs([job], force=args.force)[0]
        print(format_metrics_table([(run_label(configs[0]), summary)], first_header="Agent"))
        print(f"results: {job.out}/episodes.jsonl, {job.out}/summary.json, {job.out}/plots/"
              + (f", {job.out}/rerun/ (calnav view {job.out}/rerun/<episode>.rrd)" if job.rerun else ""))
        return
    from calnav.eval.config import expand_multirun
    from calnav.eval.objectnav.report import combo_dirname, combo_values, varied_keys, write_comparison

    combos = expand_multirun(list(args.overrides))
    keys = varied_keys(list(args.overrides))
    root = Path(args.output or configs[0].run.output_dir)
    values = [combo_values(combo, keys) for combo in combos]
    # every combination was loaded (validated) before any runs; then all their episodes run at once
    jobs = [_job(args, cfg, root / combo_dirname(v)) for cfg, v in zip(configs, values)]
    with ResultsDir(root, files=()):  # one multirun per root: its comparison covers its own runs
        summaries = run_jobs(jobs, force=args.force)
        with writing(root / "comparison.md"):
            table = write_comparison(keys, list(zip(values, summaries)), root)
    print(table)
    print(f"results: {root}/<combination>/, {root}/comparison.md, {root}/comparison.csv, {root}/comparison.png")


@dataclass
class ObjectnavArgs:
    """``calnav objectnav``'s flags."""

    agent: str | None = arg(None, "shorthand for run.agent=NAME (default: the config's, peanut)", metavar="NAME",
                            sets="run.agent")
    episodes: str = arg("10", "N (first N) or A:B (a range) of the split's episodes")
    output: str | None = arg(None, "results directory (default: run.output_dir)")
    force: bool = arg(False, "discard results of a different config in --output")
    # a video / a recording per episode, of the range's first N (0 = none)
    video: int = arg(0, "write <output>/videos/<episode_id>.mp4 for the first N episodes of the range (peanut)",
                     metavar="N", range=Range(0, 1_000_000, "episodes"))
    rerun: int = arg(0, "write <output>/rerun/<episode_id>.rrd (Rerun: camera, frames, 3D and 2D maps, metrics) for "
                        "the first N episodes of the range (peanut; needs the [viz] extra)",
                     metavar="N", range=Range(0, 1_000_000, "episodes"))
    multirun: bool = arg(False, "cross product of comma-separated overrides (KEY=a,b), one subdirectory of --output "
                                "each, then comparison.md/.csv/.png", short="-m")


COMMAND = Command(ObjectnavArgs, main_objectnav, objectnav_configs, config="configs/objectnav.yaml")
