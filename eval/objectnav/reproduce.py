"""`calnav reproduce DIR --episodes A:B`: does the code checked out now run a results directory's
episodes exactly as its records say?

A results directory resumed across commits (a study that runs for days while calnav changes)
mixes records of several commits (each record names its ``commit``); the config and input
fingerprints prove the same *inputs*, not the same *code*. This command reruns some of the
directory's episodes with its own ``config.yaml`` -- refused if the files it reads (weights,
GLFS parameters, ...) are no longer the ones ``inputs.json`` recorded, since a difference would
then prove nothing -- into a fresh results directory, and compares every field of every
record with the directory's: equal, floats within ``--tol``, where and how fast it ran
(``IGNORED_FIELDS``) aside. Exit 0 when every episode matches, 1 when one differs (each
difference printed), 2 on bad input, like every command.
"""
from __future__ import annotations

import math
import tempfile
from pathlib import Path

from calnav.eval.config import Config, ConfigError, parse_override
from calnav.eval.results_dir import (CONFIG_NAME, EPISODE_NEUTRAL_KEYS, RECORDS_NAME, ResultsDir, ResultsError,
                                     read_records)

# record fields saying where, when and by which code an episode ran, not what happened in it
IGNORED_FIELDS: tuple[str, ...] = ("wall_time_s", "commit", "ray_node", "video", "rerun")
# overrides a reproduction may take: those that cannot change a result (workers, backend)
ALLOWED_OVERRIDES: tuple[str, ...] = ("run.workers", "run.backend", "run.ray_address")


def differences(old: dict, new: dict, tol: float) -> dict[str, tuple]:
    """{field: (old value, new value)} of two records of one episode: every field either holds
    outside ``IGNORED_FIELDS``, floats equal within ``tol`` (absolute), the rest exactly; a field
    one record lacks counts as a difference (``None`` on the side that lacks it)."""
    out: dict[str, tuple] = {}
    for key in sorted((old.keys() | new.keys()) - set(IGNORED_FIELDS)):
        a, b = old.get(key), new.get(key)
        if isinstance(a, float) and isinstance(b, float) and math.isfinite(a) and math.isfinite(b):
            if abs(a - b) > tol:
                out[key] = (a, b)
        elif a != b or type(a) is not type(b) and not {type(a), type(b)} <= {int, float}:
            out[key] = (a, b)
    return out


def _source(args) -> Path:
    src = Path(args.dir)
    for name in (CONFIG_NAME, RECORDS_NAME):
        if not (src / name).is_file():
            raise FileNotFoundError(f"{src / name} not found; give a results directory of `calnav objectnav` "
                                    f"(or a study row's eval/<row>/), which holds {CONFIG_NAME} and {RECORDS_NAME}")
    return src


def reproduce_configs(args) -> list[Config]:
    """The source directory's config (its ``config.yaml``), with only result-neutral overrides."""
    from calnav.eval.shorthands import load_command_config

    if not (math.isfinite(args.tol) and args.tol >= 0):
        raise ValueError(f"--tol must be a finite number >= 0 (absolute, in each field's unit), got {args.tol}")
    cfg = load_command_config(args, config=_source(args) / CONFIG_NAME)
    for text in args.overrides:
        key = parse_override(text)[0]
        if key not in ALLOWED_OVERRIDES:
            raise ConfigError(f"{key} may change results; a reproduction runs the directory's own config "
                              f"and takes only {', '.join(ALLOWED_OVERRIDES)}")
    return [cfg]


def main_reproduce(args, configs: list[Config]) -> int:
    """Rerun ``args.episodes`` of ``args.dir`` and compare; returns the exit status (0 / 1)."""
    from calnav.eval.episodes import episode_indices
    from calnav.eval.objectnav.run import EpisodeJob, run_jobs

    src, cfg = _source(args), configs[0]
    try:   # the same config and input files as the source's records (or a locked, running directory)
        ResultsDir(src, cfg, neutral_keys=EPISODE_NEUTRAL_KEYS, option="DIR", can_force=False).check()
    except ResultsError as exc:
        raise ResultsError(f"cannot reproduce: {str(exc).rsplit('; ', 1)[0]}") from None
    old = read_records(src / RECORDS_NAME, quiet=True).records
    indices = list(episode_indices(str(args.episodes), cfg.env, cfg.run, progress=False))
    missing = [i for i in indices if i not in old]
    if missing:
        raise ConfigError(f"{src / RECORDS_NAME} holds no record of episode(s) {', '.join(map(str, missing[:8]))}"
                          f"{' ...' if len(missing) > 8 else ''}; it holds {len(old)} episodes, e.g. "
                          f"{', '.join(map(str, sorted(old)[:5]))}")
    out = Path(args.output) if args.output else Path(tempfile.mkdtemp(prefix="calnav-reproduce-"))
    run_jobs([EpisodeJob(cfg, indices, out)], force=args.force)
    new = read_records(out / RECORDS_NAME, quiet=True).records
    differing = {i: d for i in indices if (d := differences(old[i], new[i], args.tol))}
    commits = sorted({c[:7] if (c := old[i].get("commit")) else "unrecorded" for i in indices})
    for i, diff in differing.items():
        fields = "; ".join(f"{k}: {a!r} -> {b!r}" for k, (a, b) in diff.items())
        print(f"episode {i} ({old[i].get('episode_id', '?')}): {fields}")
    verdict = "every record matches" if not differing else f"{len(differing)} differ"
    print(f"reproduce: {len(indices)} episodes of {src} (recorded by {', '.join(commits)}) rerun into {out}: "
          f"{verdict} (tolerance {args.tol:g}; {', '.join(IGNORED_FIELDS)} aside)")
    return 1 if differing else 0
