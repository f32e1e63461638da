"""`calnav bench`: speed and memory figures, measured in one run on one scene.

Each section is a module of this package with ``run(ctx: BenchContext) -> dict[str, float]``,
chosen by name from ``SECTIONS``; this file owns the table and the flat JSON output
(name -> number). The sections import their heavy dependencies inside ``run``.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

from calnav.common.atomic import undefined_as_null, write_json_atomic
from calnav.eval.bench import adapter, agent, backends, env, fusion, hm3d, scan, segmenter, sequence, start_pose
from calnav.eval.bench.context import BenchContext
from dataclasses import dataclass
from calnav.common.ranges import Range
from calnav.eval.arguments import Command, arg

SECTIONS: dict[str, Callable[[BenchContext], dict[str, float]]] = {
    "env": env.run,
    "hm3d": hm3d.run,
    "fusion": fusion.run,
    "segmenter": segmenter.run,
    "adapter": adapter.run,
    "agent": agent.run,
    "sequence": sequence.run,
    "start_pose": start_pose.run,
    "backends": backends.run,
    "scan": scan.run,
}


def run_bench(output: str | Path | None, sections: tuple[str, ...] = tuple(SECTIONS), quick: bool = False,
              scene_seed: int = 7) -> dict[str, float]:
    unknown = [name for name in sections if name not in SECTIONS]
    if unknown:  # checked before any section runs
        raise ValueError(f"unknown bench section {unknown[0]!r}; valid sections: {', '.join(SECTIONS)}")
    ctx = BenchContext(scene_seed=scene_seed, quick=quick, n_poses=12 if quick else 60)
    results: dict[str, float] = {}
    for name in sections:
        t0 = time.perf_counter()
        part = SECTIONS[name](ctx)
        print(f"[bench] {name}: {len(part)} figures in {time.perf_counter() - t0:.1f} s", flush=True)
        results.update({k: float(v) for k, v in part.items()})
    print(format_table(results))
    if output:
        write_json_atomic(output, undefined_as_null(dict(sorted(results.items()))))   # a NaN figure: null
        print(f"wrote {output}")
    return results


def format_table(results: dict[str, float]) -> str:
    width = max((len(k) for k in results), default=10)
    lines = [f"{'figure':<{width}}  value", f"{'-' * width}  ---------"]
    lines += [f"{k:<{width}}  {v:.4g}" for k, v in results.items()]
    return "\n".join(lines)


def main_bench(args, configs=()) -> None:
    """`calnav bench`: ``--only`` names comma-separated sections (default: all). It reads no
    config (``configs`` is empty): each section's workload is fixed, so figures compare. The
    output gets a manifest beside it (``eval.bench.page.write_manifest``); ``--page`` renders
    pages' figure tables from the run, or with ``--from`` from an earlier output (no run)."""
    import sys

    from calnav.eval.bench.page import read_output, render_pages, write_manifest

    if args.source:   # render only: every page checked before any is written
        pages = render_pages(args.page, read_output(Path(args.source)))
    else:
        only = tuple(s for s in args.only.split(",") if s) or tuple(SECTIONS)
        for name in args.page:   # a page is checked (exists) before the run, rendered after it
            if not Path(name).is_file():
                raise ValueError(f"--page {name}: no such file")
        results = run_bench(args.output, only, quick=args.quick, scene_seed=args.scene_seed)
        if args.output:
            print(f"wrote {write_manifest(args.output, sys.argv[1:])}")
        pages = render_pages(args.page, undefined_as_null(results))
    for path, text in pages.items():
        path.write_text(text, encoding="utf-8")
        print(f"rendered {path}")


@dataclass
class BenchArgs:
    """``calnav bench``'s flags."""

    output: str = arg("bench.json", "JSON output path")
    only: str = arg("", "comma-separated sections (default: all)")
    quick: bool = arg(False, "short run (indicative numbers only)")
    scene_seed: int = arg(7, "procedural house seed to measure on", range=Range(0, 2**32 - 1))   # numpy's seeds
    page: list[str] = arg([], "a Markdown page whose '| figure | meaning | measured | target |' tables get this "
                              "run's figures (repeatable)", metavar="FILE", repeat=True)
    source: str = arg("", "render --page from this earlier bench output instead of measuring", metavar="JSON",
                      option="--from")


COMMAND = Command(BenchArgs, main_bench, sections=(), overrides=None)   # fixed workloads, no config
