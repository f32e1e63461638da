"""`calnav compare`: one comparison table from finished `calnav objectnav` run directories.

For runs made separately (e.g. each with its own tuned ``best.yaml``), this writes what a
multirun writes (``comparison.md`` / ``.csv`` / ``.png``, ``eval.objectnav.report``) with the
config keys that differ between the runs as the leading columns, plus ``paired.md`` / ``.csv``:
each run minus a baseline run on the episodes both hold (matched by index), mean and paired
SEM (``eval.stats.paired_difference``), the SEM clustered by house (``eval.stats.house_sem``), and
``|diff|`` over the larger of the two; and ``failures.md``: per run, how
many episodes failed by a false STOP, by running out of steps, or by a crash
(``eval.stats.failure_modes``, step limit from each run's ``env.max_episode_steps``), and each
run's false-STOP rate minus the baseline's, paired as Success is (``false_stop_rows``). The pairs
are the episodes both runs hold, scored as summaries score them (``eval.stats.paired_difference``:
an episode that crashed, or has a non-finite metric, is a failure with Success / SPL / SoftSPL 0;
DTG pairs finished episodes only; ``failures.md`` counts the crashes); a run with no episode
finished in both is refused (no paired difference exists), and a run holding other episodes under
the same indices (``other_episodes``) is listed unpaired; each episode
counts once (``eval.results_dir.read_records``: an exact duplicate once, two different records of one
index refused). Keys under ``mapping.`` are shown
as ``-`` for ``agent.map_type: ndf`` runs, which do not use the 3D map.
"""
from __future__ import annotations

import csv
import math
import statistics
from pathlib import Path

from calnav.eval.config import ConfigError, migrate_tree
from calnav.eval.results_dir import NEUTRAL_KEYS, flatten, read_records
from calnav.eval.stats import (COARSE_FAILURE, LINGER_STEPS, METRIC_LABELS, contrast_and_house_sem, failure_kind,
                               failure_modes, governing_sem, house_sem, is_finished, paired_difference, same_episode,
                               summarize)
from dataclasses import dataclass
from calnav.eval.arguments import REQUIRED, Command, arg

PAIRED_METRICS: tuple[str, ...] = ("spl", "success")


def load_run(path: Path) -> tuple[dict[str, object], list[dict]]:
    """(flattened config, episode records) of one run directory; its config read with moved
    keys at their new place (``eval.config.MOVED_KEYS``), so runs of before and after a move
    compare key by key."""
    import yaml

    cfg_path, eps = path / "config.yaml", path / "episodes.jsonl"
    if not cfg_path.exists() or not eps.exists():
        raise FileNotFoundError(f"{path} is not a calnav objectnav run directory "
                                "(needs config.yaml and episodes.jsonl)")
    records = list(read_records(eps).records.values())  # each episode once (different records: refused)
    if not records:
        raise ConfigError(f"{path} holds no finished episodes")
    saved = yaml.safe_load(cfg_path.read_text()) or {}
    return flatten(migrate_tree(saved) if isinstance(saved, dict) else saved), records


def differing_keys(configs: list[dict[str, object]]) -> list[str]:
    """Keys whose value is not the same in every config (a missing key counts as a value),
    in first-seen order, without the keys that never change results (NEUTRAL_KEYS)."""
    keys: list[str] = []
    for c in configs:
        keys += [k for k in c if k not in keys]
    return [k for k in keys if k not in NEUTRAL_KEYS and len({repr(c.get(k)) for c in configs}) > 1]


def cell_value(cfg: dict[str, object], key: str) -> str:
    if key.startswith("mapping.") and cfg.get("agent.map_type") == "ndf":
        return "-"
    value = cfg.get(key, "-")
    if key.endswith("resolution") and isinstance(value, list) and len(value) == 2:
        return f"{value[0]}x{value[1]}"  # the WxH form the config accepts
    return str(value)


def _ratio(d: float, sem: float) -> float:
    """|d| / SEM (inf for a nonzero d with SEM 0 over 2 or more pairs; NaN for 0 / 0 and for an
    undefined SEM: fewer than 2 pairs)."""
    if not (math.isfinite(d) and math.isfinite(sem)):
        return math.nan
    if sem > 0:
        return abs(d) / sem
    return math.inf if d != 0 else math.nan


def _ratio_cell(z: float) -> str:
    return "-" if math.isnan(z) else f"{z:.1f}"


def _diff_cell(d: float, sem: float, by_house: float) -> str:
    if math.isnan(d):
        return "-"
    return f"{d:+.3f} ({'-' if math.isnan(sem) else f'{sem:.3f}'}, {'-' if math.isnan(by_house) else f'{by_house:.3f}'})"


def episode_span(records: list[dict]) -> str:
    """'episodes A:B' (a contiguous range) or 'N episodes in A:B' of ``records``' indices."""
    idx = sorted(r["index"] for r in records)
    span = f"{idx[0]}:{idx[-1] + 1}"
    return f"episodes {span}" if len(idx) == idx[-1] + 1 - idx[0] else f"{len(idx)} episodes in {span}"


def other_episodes(base_records: list[dict], records: list[dict]) -> bool:
    """Whether ``records`` hold other episodes than the baseline's under the same indices
    (``eval.stats.same_episode``): no paired difference exists between them."""
    by_index = {r["index"]: r for r in base_records}
    return any(not same_episode(by_index[r["index"]], r) for r in records if r["index"] in by_index)


def check_shared_episodes(names: list[str], loaded: list[tuple[dict, list[dict]]], base: int) -> None:
    """Refuse (ConfigError) a run that shares no episode index with the baseline, or shares some
    but finished none of them where the baseline did too (``eval.stats.is_finished``): its paired
    difference has no pairs, so any number printed for it would be made up."""
    base_records = loaded[base][1]
    base_idx, base_ok = {r["index"] for r in base_records}, {r["index"] for r in base_records if is_finished(r)}
    for i, (name, (_, records)) in enumerate(zip(names, loaded)):
        if i == base or other_episodes(base_records, records):   # reported unpaired, not refused
            continue
        shared = base_idx & {r["index"] for r in records}
        if not shared:
            raise ConfigError(f"{name} ({episode_span(records)}) shares no episodes with the baseline "
                              f"{names[base]} ({episode_span(base_records)}); compare runs over the same "
                              "episode range (--episodes) or pick another --baseline")
        if not base_ok & {r["index"] for r in records if is_finished(r)}:
            raise ConfigError(f"{name} and the baseline {names[base]} share {len(shared)} episode(s), none of "
                              "which finished in both runs (each crashed, or has a non-finite metric, in one of "
                              "them): no paired difference exists; rerun the failed episodes (the same calnav "
                              "objectnav command retries them) or pick another --baseline")


def paired_rows(baseline: list[dict], runs: list[tuple[str, list[dict]]]) -> list[dict]:
    """One row per run: {'run', 'n', metric, metric_sem, metric_house_sem, metric_z} (run -
    baseline; ``metric_z``: |d| over the larger of the two SEMs, ``eval.stats.governing_sem``)."""
    rows = []
    for name, records in runs:
        row: dict = {"run": name, "other_episodes": other_episodes(baseline, records)}
        if row["other_episodes"]:
            row.update({f"{m}{suffix}": math.nan for m in PAIRED_METRICS for suffix in ("", "_sem", "_house_sem", "_z")},
                       n=0)
            rows.append(row)
            continue
        for m in PAIRED_METRICS:
            d, sem, n = paired_difference(baseline, records, m)
            by_house = house_sem([(baseline, -1.0), (records, 1.0)], m)
            row.update({m: d, f"{m}_sem": sem, f"{m}_house_sem": by_house,
                        f"{m}_z": _ratio(d, governing_sem(sem, by_house)), "n": n})
        rows.append(row)
    return rows


def paired_markdown(base_name: str, rows: list[dict]) -> str:
    heads = ["Run"] + [f"d{METRIC_LABELS[m]} (SEM, house SEM)" for m in PAIRED_METRICS] + \
            [f"abs d{METRIC_LABELS[m]} / larger SEM" for m in PAIRED_METRICS] + ["N paired"]
    lines = [f"Paired differences, run minus {base_name} (same episodes):", "",
             "| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    for r in rows:
        cells = [r["run"]] + [_diff_cell(r[m], r[m + "_sem"], r[m + "_house_sem"]) for m in PAIRED_METRICS] + \
                [_ratio_cell(r[m + "_z"]) for m in PAIRED_METRICS] + \
                ["0 (other episodes)" if r["other_episodes"] else str(r["n"])]
        lines.append("| " + " | ".join(cells) + " |")
    if any(r["other_episodes"] for r in rows):
        lines += ["", "other episodes: the run holds other episodes than the baseline under the same indices "
                  "(another house style, scan settings or generator): no paired difference exists; compare "
                  "their means with the unpaired SEMs of comparison.md."]
    if any(math.isnan(r[m + "_z"]) and not r["other_episodes"] for r in rows for m in PAIRED_METRICS):
        lines += ["", "abs d / SEM \"-\": the metric is identical on every paired episode, or a single episode "
                  "pairs (SEM \"-\": one difference has no spread)."]
    return "\n".join(lines)


FALSE_STOP = "false_stop"   # the per-episode indicator the paired false-STOP rate is the mean of


def max_steps(cfg: dict[str, object]) -> int:
    """A run's step limit: its ``env.max_episode_steps``, else the default."""
    from calnav.envs.config import EnvConfig

    return int(cfg.get("env.max_episode_steps", EnvConfig().max_episode_steps))


def with_false_stop(records: list[dict], limit: int) -> list[dict]:
    """``records``, each with ``FALSE_STOP`` 1.0 where it failed by a STOP away from the goal
    (``eval.stats.failure_modes``' ``false_stop``: stopped short included), else 0.0."""
    return [{**r, FALSE_STOP: float(COARSE_FAILURE.get(failure_kind(r, limit, 1.0)) == "false_stop")}
            for r in records]


def false_stop_rows(names: list[str], loaded: list[tuple[dict, list[dict]]], base: int) -> list[str]:
    """Markdown rows: per run but the baseline, its false-STOP rate minus the baseline's over the
    episodes (matched by index) finished in both (a crash is no decision), mean, paired SEM, SEM
    clustered by house and abs d over the larger; a run on other episodes is left out. A decision
    that trades false STOPs for searches that run out of steps moves this and not Success."""
    flagged = [with_false_stop(records, max_steps(cfg)) for cfg, records in loaded]
    rows = []
    for i, name in enumerate(names):
        if i == base or other_episodes(loaded[base][1], loaded[i][1]):
            continue
        d, sem, n, by_house = contrast_and_house_sem([(flagged[base], -1.0), (flagged[i], 1.0)], FALSE_STOP)
        rows.append(f"| {name} | {_diff_cell(d, sem, by_house)} | {_ratio_cell(_ratio(d, governing_sem(sem, by_house)))} "
                    f"| {n} |")
    return rows


def failures_markdown(names: list[str], loaded: list[tuple[dict, list[dict]]], base: int) -> str:
    lines = [f"| Run | Failed | False STOP | Out of steps | Crashed | At the goal > {LINGER_STEPS} steps | "
             "Median collisions | N |", "|---|---|---|---|---|---|---|---|"]
    for name, (cfg, records) in zip(names, loaded):
        f = failure_modes(records, max_steps(cfg))
        failed = f["false_stop"] + f["timeout"] + f["crashed"]
        hits = [r["collisions"] for r in records if is_finished(r) and "collisions" in r]
        median = f"{statistics.median(hits):g}" if hits else "-"
        lines.append(f"| {name} | {failed} | {f['false_stop']} | {f['timeout']} | {f['crashed']} | {f['lingered']} "
                     f"| {median} | {len(records)} |")
    paired = false_stop_rows(names, loaded, base)
    if paired:
        lines += ["", f"False-STOP rate, run minus {names[base]} (paired over the episodes finished in both):", "",
                  "| Run | dFalse STOP rate (SEM, house SEM) | abs d / larger SEM | N paired |", "|---|---|---|---|",
                  *paired]
    return "\n".join(lines)


def main_compare(args, configs=()) -> None:
    """``configs`` is empty: compare reads the finished runs' own ``config.yaml`` files."""
    from calnav.eval.objectnav.report import write_comparison

    paths = [Path(p) for p in args.runs]
    if len(paths) < 2:
        raise ConfigError("calnav compare needs at least two run directories")
    base = int(args.baseline)
    if not 0 <= base < len(paths):
        raise ConfigError(f"--baseline {base} is not a run position (0..{len(paths) - 1})")
    loaded = [load_run(p) for p in paths]
    names = [str(p) for p in paths]
    check_shared_episodes(names, loaded, base)
    configs = [c for c, _ in loaded]
    keys = [k.strip() for k in args.keys.split(",")] if args.keys else differing_keys(configs)
    unknown = [k for k in keys if not any(k in c for c in configs)]
    if unknown:
        raise ConfigError(f"--keys {', '.join(unknown)} not in any run's config; keys that differ: "
                          f"{', '.join(differing_keys(configs)) or '(none)'}")
    rows = [({k: cell_value(c, k) for k in keys}, summarize(r)) for c, r in loaded]
    if not keys:   # the same config run twice (a reproducibility check): the directories tell the rows apart
        keys, rows = ["Run"], [({"Run": name}, summary) for name, (_, summary) in zip(names, rows)]
    out = Path(args.output)
    table = write_comparison(keys, rows, out)
    others = [(names[i], loaded[i][1]) for i in range(len(paths)) if i != base]
    prow = paired_rows(loaded[base][1], others)
    paired = paired_markdown(names[base], prow)
    (out / "paired.md").write_text(paired + "\n")
    with open(out / "paired.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(prow[0]))
        w.writeheader()
        w.writerows(prow)
    failures = failures_markdown(names, loaded, base)
    (out / "failures.md").write_text(failures + "\n")
    print(table)
    print()
    print(paired)
    print()
    print(failures)
    print(f"results: {out}/comparison.md, comparison.csv, comparison.png, paired.md, paired.csv, failures.md")


@dataclass
class CompareArgs:
    """``calnav compare``'s flags."""

    runs: list[str] = arg(REQUIRED, "run directories (each with config.yaml and episodes.jsonl)", positional=True)
    keys: str = arg("", "comma-separated config keys as columns (default: the keys that differ)")
    # its range is the runs given: main_compare checks it against them
    baseline: int = arg(0, "position of the run the paired differences are taken against")
    output: str = arg(REQUIRED, "directory for comparison.md/.csv/.png and paired.md/.csv")


COMMAND = Command(CompareArgs, main_compare, sections=(), overrides=None)   # reads the runs' configs
