"""`calnav demo` (what `make demo` runs): a real ObjectNav evaluation on the built-in
procedural houses, printing the metrics table and where the results went."""
from __future__ import annotations

from pathlib import Path

from eval.config import load_config
from eval.stats import format_metrics_table


def main_demo(args) -> None:
    from envs.episodes import load_split, parse_episode_range
    from eval.objectnav import run_objectnav

    cfg = load_config("configs/demo.yaml", [f"run.output_dir={args.output}"])
    episodes = load_split(cfg.env.split, cfg.env)
    indices = list(parse_episode_range(str(args.episodes), len(episodes)))
    out = Path(cfg.run.output_dir)
    agent = "oracle"
    summary = run_objectnav(cfg, agent, indices, out, force=True)
    print()
    print(format_metrics_table([(agent, summary)], first_header="Agent"))
    print(f"\nresults: {out}/episodes.jsonl, {out}/summary.json, config: {out}/config.yaml")
