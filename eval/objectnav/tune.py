"""`calnav tune`: grid-search the goal-detection keys of the ``peanut`` agent.

The grid is ``agent.goal_threshold`` (goal-class confidence a map cell needs, unitless, in
(0, 1]) x ``agent.goal_min_area_cells`` (smallest accepted goal component, in map cells of
``agent.cell_m`` metres, >= 1). Each grid point is a resumable ``run_objectnav`` into
``<output>/<threshold>_<min_area>/`` on a tuning range of ``env.split``'s episodes, so an
interrupted tune picks up where it stopped.

Outputs: ``<output>/tune.csv`` (one row per grid point: threshold, min_area, success,
success_sem, spl, spl_sem, softspl, dtg [metres], n [episodes]) and ``<output>/best.yaml``, a
complete config (input config + overrides + tuned keys) for ``calnav objectnav --config``, whose
header comment names the tuning episode range so a disjoint evaluation range can be chosen.
With ``--extend N``, a best threshold on the edge of the grid adds up to N thresholds beyond it
(``edge_extension``), so the optimum is bracketed rather than clipped.
"""
from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any

from calnav.eval.config import Config, ConfigError, dump_yaml, load_config, parse_override
from calnav.eval.results_dir import ResultsDir
from dataclasses import dataclass
from typing import Literal
from calnav.eval.arguments import Command, arg

TUNE_METRICS: tuple[str, ...] = ("spl", "success", "softspl")  # all higher-is-better
TUNED_KEYS: tuple[str, ...] = ("agent.goal_threshold", "agent.goal_min_area_cells")
CSV_COLUMNS: tuple[str, ...] = ("threshold", "min_area", "success", "success_sem", "spl", "spl_sem",
                                "softspl", "dtg", "n")
TUNED_AGENT = "peanut"  # the agent whose goal detection the grid tunes


def _parse_list(text: str, option: str, convert, valid, description: str, example: str) -> list:
    """A comma-separated option value -> sorted unique values; ``convert`` parses one item,
    ``valid`` checks it, ``description`` names the valid range (with its unit)."""
    items = [s.strip() for s in str(text).split(",") if s.strip()]
    if not items:
        raise ConfigError(f"{option} is empty; give a comma-separated list, e.g. {option} {example}")
    values = []
    for s in items:
        try:
            v = convert(s)
        except ValueError:
            raise ConfigError(f"bad value {s!r} in {option}; expected {description}") from None
        if not valid(v):
            raise ConfigError(f"{s} in {option} is outside the valid range: {description}")
        values.append(v)
    return sorted(set(values))


def parse_thresholds(text: str) -> list[float]:
    """'0.5,0.7' -> sorted unique goal thresholds (confidence, unitless); each must be in (0, 1]."""
    return _parse_list(text, "--thresholds", float, lambda v: 0.0 < v <= 1.0,
                       "numbers in (0, 1] (goal-class confidence)", "0.5,0.7,0.9")


def parse_min_areas(text: str) -> list[int]:
    """'2,4,8' -> sorted unique minimum goal areas in map cells; each must be an integer >= 1."""
    return _parse_list(text, "--min-areas", int, lambda v: v >= 1, "integers >= 1 (map cells)", "2,4,8")


def point_name(threshold: float, min_area: int) -> str:
    """Directory name of one grid point, e.g. ``0.8_4``."""
    return f"{threshold:g}_{min_area}"


# Metric means are rounded to this many decimals before ranking: runs with identical episodes
# can differ in the last bits (episodes finish, and are summed, in a different order), and such
# noise must tie, not decide.
SCORE_DECIMALS = 9


def _score(value) -> float:
    """A metric value for ranking: missing / NaN ranks below everything."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return -math.inf
    return round(v, SCORE_DECIMALS) if math.isfinite(v) else -math.inf


def select_best(rows: list[dict], metric: str = "spl") -> dict:
    """The best grid point among ``rows`` (dicts with threshold, min_area and metric keys).

    Ranked by ``metric`` (higher is better; equal to SCORE_DECIMALS decimals is a tie), ties
    broken by higher success, then by the lower threshold, then by the smaller min_area (so the
    choice is deterministic)."""
    if metric not in TUNE_METRICS:
        raise ConfigError(f"unknown tuning metric {metric!r}; valid: {', '.join(TUNE_METRICS)}")
    if not rows:
        raise ConfigError("no grid points to select from (empty grid)")
    return max(rows, key=lambda r: (_score(r.get(metric)), _score(r.get("success")),
                                    -float(r["threshold"]), -int(r["min_area"])))


def summary_row(threshold: float, min_area: int, summary: dict) -> dict:
    """One tune.csv row from a ``run_objectnav`` summary (DTG in metres, n in episodes)."""
    return {"threshold": threshold, "min_area": min_area,
            "success": summary["success"], "success_sem": summary["success_sem"],
            "spl": summary["spl"], "spl_sem": summary["spl_sem"], "softspl": summary["softspl"],
            "dtg": summary["distance_to_goal"], "n": summary["count"]}


def csv_text(rows: list[dict]) -> str:
    """tune.csv's contents: a header of CSV_COLUMNS, then one line per row."""
    buf = io.StringIO(newline="")
    w = csv.DictWriter(buf, fieldnames=list(CSV_COLUMNS))
    w.writeheader()
    for r in rows:
        w.writerow({k: r[k] for k in CSV_COLUMNS})
    return buf.getvalue()


def best_yaml_text(cfg: Config, *, config_path: str | None, overrides: list[str], split: str,
                   episodes: range, metric: str, best: dict, n_points: int) -> str:
    """Complete config YAML of the tuned agent with a header naming the tuning range and metric."""
    header = [
        "# calnav tune result: a complete config for `calnav objectnav --agent peanut --config <this file>`.",
        f"# Tuned agent.goal_threshold={best['threshold']:g}, agent.goal_min_area_cells={best['min_area']}"
        f" over {n_points} grid points by {metric} (tie-break: success, then lower threshold).",
        f"# Tuning episodes: {split} split, episodes {episodes.start}:{episodes.stop}"
        f" ({len(episodes)} episodes). Evaluate on a DISJOINT range (not {episodes.start}:{episodes.stop}).",
        f"# Tuning result: {metric}={best[metric]:.4f}, success={best['success']:.4f}, n={best['n']}.",
        f"# Source: --config {config_path}" + (f" with overrides: {' '.join(overrides)}" if overrides else ""),
    ]
    return "\n".join(header) + "\n" + dump_yaml(cfg)


def grid_scores(rows: list[dict], metric: str) -> dict[float, tuple]:
    """threshold -> its best (metric, success) over the grid's min areas, ranked as
    ``select_best`` ranks them (``edge_extension``'s ``scores``)."""
    scores: dict[float, tuple] = {}
    for r in rows:
        key = (_score(r[metric]), _score(r["success"]))
        scores[r["threshold"]] = max(scores.get(r["threshold"], key), key)
    return scores


def edge_extension(scores: dict[float, Any]) -> float | None:
    """The next threshold to try when the best one (``scores``: threshold -> its best metric
    value, higher is better, or a tuple of values compared in order as ``select_best`` ranks
    them; ties go to the lower threshold) sits on an edge of the grid and
    beats its neighbour: halfway to 1 above the top, one grid spacing below the bottom (if that
    stays > 0). None when the best is interior, ties with its neighbour (a flat optimum needs
    no bracketing), or there is nowhere to go."""
    ts = sorted(scores)
    rank = {t: v if isinstance(v, tuple) else _score(v) for t, v in scores.items()}
    best = max(ts, key=lambda t: (rank[t], -t))
    if len(ts) == 1:
        return round((best + 1.0) / 2.0, 4) if best < 1.0 else None
    if best == ts[-1] and rank[ts[-1]] > rank[ts[-2]] and best < 1.0:
        return round((best + 1.0) / 2.0, 4)
    if best == ts[0] and rank[ts[0]] > rank[ts[1]]:
        spacing = ts[1] - ts[0]
        if ts[0] - spacing > 0:
            return round(ts[0] - spacing, 4)
    return None


def run_tune(config_path: str | None, overrides: list[str], episodes: str, thresholds: str,
             min_areas: str, metric: str, out: Path, force: bool = False,
             progress: bool = True, extend: int = 0) -> tuple[list[dict], dict]:
    """Run the grid (resumably) and write tune.csv and best.yaml under ``out``. ``extend``:
    up to this many extra thresholds (``edge_extension``) while the best one is on an edge.

    Returns (rows, best row); every row holds the tune.csv columns."""
    from calnav.eval.episodes import episode_indices
    from calnav.eval.objectnav.run import EpisodeJob, run_jobs

    if metric not in TUNE_METRICS:
        raise ConfigError(f"unknown tuning metric {metric!r}; valid: {', '.join(TUNE_METRICS)}")
    ts, areas = parse_thresholds(thresholds), parse_min_areas(min_areas)
    if extend < 0:
        raise ConfigError(f"--extend must be >= 0, got {extend}")
    overrides = list(overrides)
    for text in overrides:
        if parse_override(text)[0] in TUNED_KEYS:
            raise ConfigError(f"{parse_override(text)[0]} is tuned by --thresholds / --min-areas; "
                              "remove it from the overrides")
    base = load_config(config_path, overrides)
    if base.run.agent != TUNED_AGENT:
        raise ConfigError(f"calnav tune tunes the {TUNED_AGENT} agent's goal detection; "
                          f"run.agent is {base.run.agent!r} (set run.agent={TUNED_AGENT})")

    def point_config(t: float, a: int) -> Config:
        """The config of grid point (threshold, min area); raises ConfigError if refused."""
        return load_config(config_path, overrides + [f"agent.goal_threshold={t}", f"agent.goal_min_area_cells={a}"])

    for t in ts:   # every grid point's config is checked before the output directory is touched
        for a in areas:
            point_config(t, a)
    indices = episode_indices(str(episodes), base.env, base.run, progress)
    out = Path(out)
    rows: list[dict] = []

    def run_thresholds(thresholds: list[float]) -> None:
        """Every (threshold, min area) point of ``thresholds`` as one batch of jobs, so all
        their episodes are in flight together (a cluster stays busy)."""
        points = [(t, a) for t in thresholds for a in areas]
        jobs = []
        for t, a in points:
            cfg = point_config(t, a)
            if progress:
                print(f"tune: goal_threshold={t:g} goal_min_area_cells={a} -> {out / point_name(t, a)}")
            jobs.append(EpisodeJob(cfg, list(indices), out / point_name(t, a)))
        for (t, a), summary in zip(points, run_jobs(jobs, force=force, progress=progress)):
            rows.append(summary_row(t, a, summary))

    # the root holds no config of its own (each grid point checks its own): a lock only, so two
    # tunes into one --output cannot interleave their grids and tune.csv
    with ResultsDir(out, files=("tune.csv", "best.yaml")) as root:
        run_thresholds(ts)
        for _ in range(extend):
            nxt = edge_extension(grid_scores(rows, metric))
            if nxt is None or nxt in ts:
                break
            try:   # e.g. an uncertainty-aware agent's band [uncertain_low, threshold) would be empty
                for a in areas:
                    point_config(nxt, a)
            except ConfigError as e:
                print(f"tune: not extending to goal_threshold={nxt:g}: {e}")
                break
            ts = sorted(ts + [nxt])
            run_thresholds([nxt])
        rows.sort(key=lambda r: (r["threshold"], r["min_area"]))
        root.write_text("tune.csv", csv_text(rows))
        best = select_best(rows, metric)
        best_cfg = point_config(best["threshold"], best["min_area"])
        root.write_text("best.yaml", best_yaml_text(
            best_cfg, config_path=config_path, overrides=overrides, split=base.env.split, episodes=indices,
            metric=metric, best=best, n_points=len(rows)))
    return rows, best


def format_tune_table(rows: list[dict], best: dict) -> str:
    """Markdown table of the grid (metric as 'mean (SEM)', DTG in metres); best row marked '*'."""
    lines = ["| threshold | min_area | Success | SPL | SoftSPL | DTG (m) | N |", "|" + "---|" * 7]
    for r in rows:
        mark = " *" if r is best else ""
        lines.append(f"| {r['threshold']:g}{mark} | {r['min_area']} | {r['success']:.3f} ({r['success_sem']:.3f}) "
                     f"| {r['spl']:.3f} ({r['spl_sem']:.3f}) | {r['softspl']:.3f} | {r['dtg']:.2f} | {r['n']} |")
    return "\n".join(lines)


def tune_configs(args) -> list:
    """The config ``calnav tune`` runs: the base every grid point adds its two tuned keys to
    (they name no file, so the preflight checks the base)."""
    from calnav.eval.shorthands import load_command_config

    return [load_command_config(args)]


def main_tune(args, configs) -> None:
    """``configs``: ``tune_configs(args)``, checked by the preflight; ``run_tune`` loads each
    grid point from the same config file and overrides."""
    out = Path(args.output)
    rows, best = run_tune(args.config, args.overrides, args.episodes, args.thresholds, args.min_areas,
                          args.metric, out, force=args.force, extend=args.extend)
    print(format_tune_table(rows, best))
    print(f"best by {args.metric}: agent.goal_threshold={best['threshold']:g} "
          f"agent.goal_min_area_cells={best['min_area']} ({args.metric}={best[args.metric]:.3f}, "
          f"success={best['success']:.3f}, n={best['n']})")
    print(f"results: {out}/tune.csv, {out}/best.yaml (tuned on episodes {args.episodes}; "
          "evaluate on a disjoint range)")


@dataclass
class TuneArgs:
    """``calnav tune``'s flags."""

    episodes: str = arg("0:100", "tuning range of the split's episodes: N or A:B")
    thresholds: str = arg("0.5,0.6,0.7,0.8,0.9", "comma-separated goal confidence thresholds, each in (0, 1]")
    min_areas: str = arg("2,4,8", "comma-separated minimum goal areas, map cells (>= 1)")
    metric: Literal["spl", "success", "softspl"] = arg("spl", "selection metric")
    # >= 0: run_tune checks it (it is run_tune's argument too)
    extend: int = arg(0, "while the best threshold is on the grid's edge, try up to this many more beyond it")
    output: str = arg("runs/tune", "results directory (one subdirectory per grid point)")
    force: bool = arg(False, "discard results of a different config in --output")


COMMAND = Command(TuneArgs, main_tune, tune_configs, config="configs/objectnav.yaml")
