"""`calnav habitat-benchmark`: run an agent through habitat-lab's ``habitat.Benchmark`` on calnav
houses and write ``calnav objectnav``'s results files.

Config: two layers. ``--habitat-config`` (default ``configs/habitat_objectnav.yaml``, which
extends habitat-lab's ``benchmark/nav/objectnav/objectnav_hm3d.yaml``) with ``habitat.*``
overrides sets the task, sensors, agent body and split; ``--config`` (default
``configs/objectnav.yaml``) with the other overrides sets the agent (``run.agent``,
``agent.*``, ``mapping.*``) and the houses (``env.dataset.*``, navigation grid). An ``env.*``
override of a key the habitat config owns (``envs.habitat_config.HABITAT_OWNED``) is refused.

The episode loop is habitat-lab's own (``Benchmark.local_evaluate``); a thin wrapper around
its ``habitat.Env`` records each episode's metrics when the benchmark reads them.
Output directory: ``config.yaml`` (calnav config, ``env`` as the habitat config sets it),
``habitat_config.yaml`` (the composed habitat-lab config), ``episodes.jsonl``,
``summary.json``, ``plots/`` -- the records and summary of ``calnav objectnav`` (habitat-lab's
``soft_spl`` is written as ``softspl``). Rerunning into the same directory skips finished
episodes; a directory holding another config is refused unless ``--force``.
"""
from __future__ import annotations

from pathlib import Path

from calnav.eval.config import ConfigError
from calnav.eval.objectnav.run import RUN_RESULTS, check_not_all_failed, crashed
from calnav.eval.results_dir import EPISODE_NEUTRAL_KEYS, ResultsDir, writing
from calnav.eval.stats import format_metrics_table, run_label, summarize
from dataclasses import dataclass
from calnav.eval.arguments import Command, arg

HABITAT_PREFIX = "habitat."
HABITAT_CONFIG_FILE = "habitat_config.yaml"


def split_overrides(overrides: list[str]) -> tuple[list[str], list[str]]:
    """(habitat.* overrides, calnav overrides); a calnav ``env.<habitat-owned key>`` is an error."""
    from calnav.envs.habitat_config import HABITAT_OWNED

    hab = [o for o in overrides if o.startswith(HABITAT_PREFIX)]
    own = [o for o in overrides if not o.startswith(HABITAT_PREFIX)]
    for o in own:
        key = o.split("=", 1)[0]
        if key.startswith("env.") and key[len("env."):] in HABITAT_OWNED:
            raise ConfigError(f"{key} is set by the habitat config in habitat-benchmark; override the habitat key "
                              f"instead (e.g. habitat.simulator.turn_angle=..., habitat.dataset.split=...); "
                              f"habitat-owned env keys: {', '.join(HABITAT_OWNED)}")
    return hab, own


def _check_habitat_config(out: Path, text: str, force: bool) -> None:
    """Refuse (unless ``force``, which discards the run's results) a directory whose saved
    habitat config differs from ``text``; calnav's own config is ResultsDir's check."""
    path = out / HABITAT_CONFIG_FILE
    if path.exists() and path.read_text() != text:
        if not force:
            raise ConfigError(f"{out} holds results of a different habitat config ({path}); "
                              "use another --output, or --force to discard them")
        for name in RUN_RESULTS:
            target = out / name
            if target.is_file():
                target.unlink()


def simulator_handle(env, env_cfg):
    """The privileged handle (``envs.task.SimulatorHandle``) of ``env``, a habitat.Env on
    ``CalnavSim-v0``: the shortest-path follower on the simulator's navigation grid and pose, to
    the view points of habitat-lab's current episode; ``env_cfg``: the EnvConfig of the habitat
    config (``envs.habitat_config.env_config_from_habitat``: step, turns, success distance,
    step limit). ``agent.setup.build_agent`` hands it only to an agent that declares it."""
    from calnav.envs.oracle import FollowerHandle

    def goal_field():
        ep = env.current_episode
        return env.sim.goal_field([v.agent_state.position for g in ep.goals for v in g.view_points])

    return FollowerHandle(lambda: env.sim.navgrid, lambda: env_cfg, lambda: (env.sim.position, env.sim.yaw),
                          goal_field)


def run_habitat_benchmark(cfg, habitat_cfg, indices: list[int], out: Path, force: bool = False,
                          progress: bool = True, plots: bool = True) -> dict:
    """Run (or resume) ``indices`` of the habitat config's split with agent ``cfg.run.agent``
    through ``habitat.Benchmark``; returns the summary dict (also in ``out/summary.json``).
    The directory is owned by ``eval.results_dir`` as ``calnav objectnav``'s is (lock, config
    check, records file with crashed episodes retried)."""
    import calnav.envs.habitat_sim_backend  # noqa: F401  (registers CalnavSim-v0)
    from omegaconf import OmegaConf

    from calnav.agent.habitat_agent import HabitatAgent, habitat
    from calnav.agent.navigator import Navigator
    from calnav.envs.episodes import load_split
    from calnav.eval.config import agent_setup
    from calnav.eval.habitat.recording import EnvBenchmark, RecordingEnv, episode_index

    habitat_text = OmegaConf.to_yaml(habitat_cfg, resolve=True)
    agent_name = cfg.run.agent
    from functools import partial

    from calnav.eval.episodes import other_recorded_episodes

    with ResultsDir(out, cfg, force=force, discard=RUN_RESULTS, neutral_keys=EPISODE_NEUTRAL_KEYS,
                    other_records=partial(other_recorded_episodes, cfg.env, indices=list(indices))) as results:
        _check_habitat_config(out, habitat_text, force)
        results.write_text(HABITAT_CONFIG_FILE, habitat_text)
        records_file = results.records()
        resumed = records_file.resume(retry=crashed, indices=indices)
        wanted = set(indices)
        records = {i: r for i, r in resumed.records.items() if i in wanted}
        todo = [i for i in indices if i not in records]
        if todo:
            calnav_eps = load_split(cfg.env.split, cfg.env, progress=progress)
            index_of = episode_index(calnav_eps)
            env = habitat.Env(config=habitat_cfg)
            by_index = {index_of[(Path(e.scene_id).name, e.episode_id)]: e for e in env.episodes}
            env.episodes = [by_index[i] for i in todo]
            agent = HabitatAgent(Navigator(agent_setup(cfg), simulator=simulator_handle(env, cfg.env)))
            with records_file:
                def record(rec: dict) -> None:
                    records_file.append(rec)
                    records[rec["index"]] = rec

                bench = EnvBenchmark(RecordingEnv(env, index_of, record, cfg.env.success_distance_m))
                try:  # finished episodes are on disk already; an error stops the run (rerun resumes)
                    bench.evaluate(agent, num_episodes=len(todo))
                finally:
                    env.close()
        ordered = [records[i] for i in indices if i in records]
        summary = summarize(ordered)
        summary["agent"] = agent_name
        summary["duplicates"] = resumed.duplicates
        results.write_json("summary.json", summary)
        if plots and ordered:
            from calnav.eval.objectnav.report import plot_run

            with writing(out / "plots"):
                plot_run(summary, out, title=f"{agent_name} (habitat-lab)")
    check_not_all_failed(ordered)
    return summary


def load_configs(args, overrides: list[str]):
    """(calnav Config, habitat config) from the parsed args; one-line errors on bad keys."""
    from calnav.envs.habitat_config import habitat_config

    hab, own = split_overrides(list(overrides))
    from calnav.eval.shorthands import load_command_config

    cfg = load_command_config(args, own)   # with the command's shorthands (--agent)
    habitat_cfg, env = habitat_config(cfg.env, hab, config_path=args.habitat_config)
    cfg.env = env
    return cfg, habitat_cfg


def habitat_benchmark_configs(args) -> list:
    """What ``calnav habitat-benchmark`` runs: [calnav config, habitat-lab config] (the second is
    validated by habitat-lab's own loader)."""
    from calnav.common.habitat_import import HabitatMissing

    try:
        configs = list(load_configs(args, args.overrides))
    except HabitatMissing as exc:
        raise ConfigError(str(exc)) from None
    if configs[0].env.dataset.data_path:   # CalnavSim-v0 serves calnav's own houses by their split directory
        raise ConfigError("habitat-benchmark runs calnav's generated episodes on CalnavSim-v0; env.dataset.data_path "
                          "names a habitat-lab episode file: run it with calnav objectnav (calnav's simulator), or "
                          "with habitat-lab on habitat-sim")
    return configs


def main_habitat_benchmark(args, configs) -> None:
    """``configs``: ``habitat_benchmark_configs(args)``, checked by the preflight."""
    from calnav.envs.episodes import load_split, parse_episode_range

    cfg, habitat_cfg = configs
    episodes = load_split(cfg.env.split, cfg.env)
    indices = list(parse_episode_range(str(args.episodes), len(episodes)))
    out = Path(args.output or cfg.run.output_dir)
    summary = run_habitat_benchmark(cfg, habitat_cfg, indices, out, force=args.force)
    print(format_metrics_table([(f"{run_label(cfg)} (habitat-lab)", summary)], first_header="Agent"))
    print(f"results: {out}/episodes.jsonl, {out}/summary.json, {out}/plots/")


@dataclass
class HabitatBenchmarkArgs:
    """``calnav habitat-benchmark``'s flags."""

    habitat_config: str = arg("configs/habitat_objectnav.yaml",
                              "habitat-lab config (task, sensors, split); habitat.* overrides apply to it")
    agent: str | None = arg(None, "shorthand for run.agent=NAME (default: the config's, peanut)", metavar="NAME",
                            sets="run.agent")
    episodes: str = arg("10", "N (first N) or A:B (a range) of the split's episodes")
    output: str | None = arg(None, "results directory (default: run.output_dir)")
    force: bool = arg(False, "discard results of a different config in --output")


COMMAND = Command(HabitatBenchmarkArgs, main_habitat_benchmark, habitat_benchmark_configs,
                  config="configs/objectnav.yaml")
