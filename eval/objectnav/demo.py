"""`calnav demo` (what `make demo` runs): a real ObjectNav evaluation on the built-in
procedural houses -- the PEANUT-like agent with the shipped learned RGB segmenter and GLFS
fusion (``configs/demo.yaml``) -- printing the metrics table and where the results, plots and
one episode video went."""
from __future__ import annotations

from pathlib import Path

from calnav.eval.shorthands import load_command_config
from calnav.eval.stats import format_metrics_table, run_label
from dataclasses import dataclass
from calnav.eval.arguments import Command, arg

def demo_configs(args) -> list:
    """The config ``calnav demo`` runs: ``configs/demo.yaml`` and the overrides, writing to
    ``--output`` (``run.output_dir``)."""
    return [load_command_config(args, config="configs/demo.yaml")]


def main_demo(args, configs) -> None:
    """``configs``: ``demo_configs(args)``, checked by the preflight."""
    from calnav.eval.episodes import episode_indices
    from calnav.eval.objectnav.run import run_objectnav

    cfg = configs[0]
    indices = episode_indices(str(args.episodes), cfg.env, cfg.run)
    out = Path(cfg.run.output_dir)
    summary = run_objectnav(cfg, indices, out, force=True, video=1)
    print()
    print(format_metrics_table([(run_label(cfg), summary)], first_header="Agent"))
    videos = sorted((out / "videos").glob("*.mp4"))
    print(f"\nresults: {out}/episodes.jsonl, {out}/summary.json, config: {out}/config.yaml")
    print(f"plots:   {out}/plots/")
    if videos:
        print(f"video:   {videos[0]}")


@dataclass
class DemoArgs:
    """``calnav demo``'s flags."""

    episodes: int = arg(5, "number of val episodes")   # checked against the split by episode_indices
    output: str | None = arg(None, "results directory; shorthand for run.output_dir (default runs/demo)",
                             sets="run.output_dir", sets_default="runs/demo")


COMMAND = Command(DemoArgs, main_demo, demo_configs,
                  overrides="dotted config overrides of configs/demo.yaml, e.g. run.workers=2")
