"""`calnav reproduce DIR --episodes A:B`: does the code checked out now run a results directory's
episodes exactly as its records say?

A results directory resumed across commits (a study that runs for days while calnav changes)
mixes records of several commits (each record names its ``commit``); the config and input
fingerprints prove the same *inputs*, not the same *code*. This command reruns some of the
directory's episodes with its own ``config.yaml`` -- refused if the files it reads (weights,
GLFS parameters, ...) are no longer the ones ``inputs.json`` recorded, since a difference would
then prove nothing -- into a fresh results directory, and compares every field of every
record with the directory's: equal, numbers within ``--tol``, where and how fast it ran
(``RECORD_PROVENANCE``) aside. Exit 0 when every episode matches, 1 when one differs (each
difference printed; a crash is a record like any other), 2 on bad input, like every command.

The rerun goes to a new directory (``--output``, default a new temporary one): one that holds
records already is refused, since resuming it would compare records that never reran. DIR is
only read. What it reproduces is a directory of ``calnav objectnav``, ``calnav tune`` (a grid
point) or a study row: episodes of calnav's ObjectNav env under the directory's config (the
start-pose study's frame-change variants and habitat-benchmark runs use other envs). A
record's ``commit`` is the checkout's HEAD: uncommitted edits do not show in it. Records that
name other episodes than the split holds now (scans made on another kind of machine) are
refused: on other episodes the code is not compared at all.
"""
from __future__ import annotations

import math
import tempfile
from numbers import Real
from dataclasses import dataclass
from pathlib import Path

from calnav.eval.config import Config, ConfigError, parse_override
from calnav.eval.results_dir import (CONFIG_NAME, EPISODE_NEUTRAL_KEYS, NEUTRAL_KEYS, RECORD_PROVENANCE, RECORDS_NAME,
                                     AllEpisodesFailed, ResultsDir, ResultsError, read_records)
from calnav.common.ranges import Range
from calnav.eval.arguments import REQUIRED, Command, arg

# overrides a reproduction may take: those that cannot change a result (its output is --output)
ALLOWED_OVERRIDES: tuple[str, ...] = tuple(k for k in NEUTRAL_KEYS if k != "run.output_dir")


def _number(x) -> bool:
    return isinstance(x, Real) and not isinstance(x, bool)


def differences(old: dict, new: dict, tol: float) -> dict[str, tuple]:
    """{field: (old value, new value)} of two records of one episode: every field either holds
    outside ``RECORD_PROVENANCE``, numbers equal within ``tol`` (absolute; 40 and 40.0 are one
    number), the rest exactly; a field one record lacks counts as a difference (``None`` on the
    side that lacks it)."""
    out: dict[str, tuple] = {}
    for key in sorted((old.keys() | new.keys()) - set(RECORD_PROVENANCE)):
        a, b = old.get(key), new.get(key)
        if _number(a) and _number(b) and math.isfinite(a) and math.isfinite(b):
            if abs(a - b) > tol:
                out[key] = (a, b)
        elif a != b or type(a) is not type(b):
            out[key] = (a, b)
    return out


def _source(args) -> Path:
    src = Path(args.dir)
    if not src.is_dir():
        raise FileNotFoundError(f"{src} is not a directory; give a results directory of `calnav objectnav`, "
                                f"`calnav tune` or a study row (its eval/<row>/), which holds {CONFIG_NAME} and "
                                f"{RECORDS_NAME}")
    for name in (CONFIG_NAME, RECORDS_NAME):
        if not (src / name).is_file():
            raise FileNotFoundError(f"{src / name} is not a file; give a results directory of `calnav objectnav`, "
                                    f"`calnav tune` or a study row, which holds {CONFIG_NAME} and {RECORDS_NAME}")
    return src


def reproduce_configs(args) -> list[Config]:
    """The source directory's config (its ``config.yaml``), with only result-neutral overrides."""
    from calnav.eval.shorthands import load_command_config

    cfg = load_command_config(args, config=_source(args) / CONFIG_NAME)
    for text in args.overrides:
        key = parse_override(text)[0]
        if key not in ALLOWED_OVERRIDES:
            raise ConfigError(f"{key}: a reproduction runs the directory's own config and takes only keys that "
                              f"cannot change results: {', '.join(ALLOWED_OVERRIDES)}")
    return [cfg]


def _check_output(out: Path, src: Path) -> None:
    """The rerun's directory must be new or hold no records: a resumed one would compare
    records that were never rerun."""
    if out.resolve() == src.resolve():
        raise ResultsError(f"--output {out} is DIR itself; give a new directory for the rerun")
    if (out / RECORDS_NAME).is_file() and read_records(out / RECORDS_NAME, quiet=True).records:
        raise ResultsError(f"--output {out} already holds records; a reproduction reruns every episode, so give a "
                           "new directory (or remove it)")


def main_reproduce(args, configs: list[Config]) -> int:
    """Rerun ``args.episodes`` of ``args.dir`` and compare; returns the exit status (0 / 1)."""
    from calnav.envs.episodes import parse_episode_range
    from calnav.eval.episodes import episode_indices, other_recorded_episodes
    from calnav.eval.objectnav.run import EpisodeJob, run_jobs

    src, cfg = _source(args), configs[0]
    try:   # the same config and input files as the source's records (or a locked, running directory)
        ResultsDir(src, cfg, neutral_keys=EPISODE_NEUTRAL_KEYS, option="DIR", can_force=False).check(read_only=True)
    except ResultsError as exc:
        raise ResultsError(f"cannot reproduce: {str(exc).rsplit('; ', 1)[0]}") from None
    old = read_records(src / RECORDS_NAME).records   # (damaged or duplicate lines: warned)
    wanted = parse_episode_range(str(args.episodes), None)   # before any scene is generated
    missing = [i for i in wanted if i not in old]
    if missing:
        held = f"it holds {len(old)} episodes, e.g. {', '.join(map(str, sorted(old)[:5]))}" if old else \
            "it holds no episode"
        raise ConfigError(f"{src / RECORDS_NAME} holds no record of episode(s) {', '.join(map(str, missing[:8]))}"
                          f"{' ...' if len(missing) > 8 else ''}; {held}")
    if args.output:
        _check_output(Path(args.output), src)
    indices = list(episode_indices(str(args.episodes), cfg.env, cfg.run, progress=False))
    other = other_recorded_episodes(cfg.env, src / RECORDS_NAME, indices)
    if other is not None:   # the code cannot be compared on other episodes (scans made on another machine)
        raise ResultsError(f"cannot reproduce: {src}'s records name other episodes: {other}")
    out = Path(args.output) if args.output else Path(tempfile.mkdtemp(prefix="calnav-reproduce-"))
    print(f"reproduce: rerunning {len(indices)} episode(s) of {src} into {out}")
    try:
        run_jobs([EpisodeJob(cfg, indices, out)], force=args.force)
    except AllEpisodesFailed:   # every rerun crashed: a result to compare like any other (records are kept)
        pass
    new = read_records(out / RECORDS_NAME, quiet=True).records
    differing = {i: d for i in indices if (d := differences(old[i], new[i], args.tol))}
    commits = sorted({c[:7] if (c := old[i].get("commit")) else "unrecorded" for i in indices})
    for i, diff in differing.items():
        fields = "; ".join(f"{k}: {a!r} -> {b!r}" for k, (a, b) in diff.items())
        print(f"episode {i} ({old[i].get('episode_id', '?')}): {fields}")
    verdict = "every record matches" if not differing else f"{len(differing)} of them differ"
    print(f"reproduce: {len(indices)} episode(s) of {src} (recorded by {', '.join(commits)}) rerun into {out}: "
          f"{verdict} (tolerance {args.tol + 0.0:g}; {', '.join(RECORD_PROVENANCE)} aside)")
    return 1 if differing else 0


@dataclass
class ReproduceArgs:
    """``calnav reproduce``'s flags."""

    dir: str = arg(REQUIRED, "a calnav objectnav results directory (config.yaml, episodes.jsonl), e.g. a study "
                             "row's eval/<row>/", positional=True)
    episodes: str = arg(REQUIRED, "N (first N) or A:B of the split's episodes; each must have a record in DIR")
    output: str = arg("", "results directory of the rerun (default: a new temporary one)")
    force: bool = arg(False, "discard results of a different config in --output")
    tol: float = arg(1e-9, "absolute tolerance of float fields (default 1e-9)",
                     range=Range(0, 1e9))   # absolute, in each field's unit


COMMAND = Command(ReproduceArgs, main_reproduce, reproduce_configs, status=True,
                  overrides="only run.workers, run.backend, run.ray_address (a reproduction runs DIR's config)")
