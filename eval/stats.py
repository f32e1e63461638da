"""Summary statistics of episode results: mean and standard error of the mean (SEM).

Every mean is over one set of episodes, never over the episodes where a metric happens to be a
number: a finished record (``status: ok``) whose metric is missing or not finite (a NaN SPL, an
infinite distance to an unreachable goal) is an error record (``finite_or_error``: status
``error``, counted in ``failed``, retried on resume), and an error record scores 0 in Success,
SPL and SoftSPL. So Success, SPL and SoftSPL are means over all episodes, and DistanceToGoal --
which a crashed episode does not have -- over the finished ones (``count - failed``); a mean of
no episodes is ``None`` (JSON null, ``-`` in tables), never NaN.
"""
from __future__ import annotations

import math

import numpy as np

METRICS: tuple[str, ...] = ("success", "spl", "softspl", "distance_to_goal")
METRIC_LABELS: dict[str, str] = {"success": "Success", "spl": "SPL", "softspl": "SoftSPL",
                                 "distance_to_goal": "DTG"}
FAILURE_SCORED: tuple[str, ...] = ("success", "spl", "softspl")   # 0 for an error record; DTG: finished only


def mean_sem(values) -> tuple[float, float]:
    """Mean and SEM = sample std (ddof=1) / sqrt(n); SEM is 0 for n = 1, NaN for n = 0."""
    x = np.asarray(list(values), dtype=np.float64)
    if len(x) == 0:
        return math.nan, math.nan
    if len(x) == 1:
        return float(x[0]), 0.0
    return float(x.mean()), float(x.std(ddof=1) / math.sqrt(len(x)))


def _finite_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def is_finished(record: dict) -> bool:
    """A finished episode (``status`` ok) whose every metric is a finite number."""
    return record.get("status", "ok") == "ok" and all(_finite_number(record.get(m)) for m in METRICS)


def finite_or_error(record: dict) -> dict:
    """``record`` when it is an error record already or every metric is a finite number;
    otherwise the error record it becomes: ``status: error``, an ``error`` naming the metrics,
    and those values removed (so the record stays strict JSON). Applied where records are made
    (``eval.objectnav.run``, ``eval.habitat.recording``) and read (``eval.results_dir``)."""
    if record.get("status", "ok") != "ok" or is_finished(record):
        return record
    bad = {m: record.get(m) for m in METRICS if not _finite_number(record.get(m))}
    shown = ", ".join(f"{m} {v}" for m, v in bad.items())
    return {**{k: v for k, v in record.items() if k not in bad}, "status": "error",
            "error": f"non-finite metrics ({shown}): an episode without a finite score counts as failed"}


def _mean_sem_or_none(values: list[float]) -> tuple[float | None, float | None]:
    """``mean_sem``, with None (JSON null) instead of NaN for no values."""
    if not values:
        return None, None
    return mean_sem(values)


def _means(rows: list[dict]) -> dict:
    """{metric: mean, metric_sem: SEM} of scored rows (module docstring: one episode set per
    metric kind, never a per-metric filter)."""
    out: dict = {}
    finished = [r for r in rows if r.get("status", "ok") == "ok"]
    for m in METRICS:
        over = rows if m in FAILURE_SCORED else finished
        out[m], out[f"{m}_sem"] = _mean_sem_or_none([float(r[m]) for r in over])
    return out


def summarize(records: list[dict]) -> dict:
    """Episode records -> {metric: mean, metric_sem: SEM, count, failed, per_category: {...}}.
    Error records (crashed episodes, and finished ones with a non-finite metric) count in
    ``failed`` and as failures with Success / SPL / SoftSPL 0 (module docstring)."""
    rows = [scored(r) for r in records]
    failed = sum(r.get("status", "ok") != "ok" for r in rows)
    out: dict = {"count": len(records), "failed": failed, **_means(rows)}
    per_cat: dict[str, dict] = {}
    for cat in sorted({r["category"] for r in rows if "category" in r}):
        sub = [r for r in rows if r.get("category") == cat]
        per_cat[cat] = {"count": len(sub), **_means(sub)}
    out["per_category"] = per_cat
    return out


def scored(record: dict) -> dict:
    """The record as it is scored: an error record (``finite_or_error``: a crash, or a
    non-finite metric) counts as a failure (Success, SPL, SoftSPL 0)."""
    record = finite_or_error(record)
    if record.get("status", "ok") == "ok":
        return record
    return {**record, **{m: 0.0 for m in FAILURE_SCORED}}


EPISODE_KEYS: tuple[str, ...] = ("episode_id", "geodesic_distance")   # what names an episode in a record


def same_episode(a: dict, b: dict) -> bool:
    """Whether two records of one index are the same episode: their ``EPISODE_KEYS`` agree
    (where both hold them). Runs on other datasets (another house style, scan settings or
    generator) reuse indices and ids for other starts; their geodesic distances differ."""
    return all(a[k] == b[k] for k in EPISODE_KEYS if k in a and k in b)


def paired_difference(a: list[dict], b: list[dict], metric: str) -> tuple[float, float, int]:
    """Mean and SEM of ``metric``(b) - ``metric``(a) over the episodes (matched by ``index``)
    both runs hold, scored as ``summarize`` scores them: an error record (a crash, a non-finite
    metric) is a failure with Success / SPL / SoftSPL 0, so a run that crashes on the hard
    episodes is not flattered; DistanceToGoal pairs only episodes both runs finished. Returns
    the mean, the SEM and the number of pairs. Pairing removes the episode-difficulty variance
    both runs share, so this SEM is the one that says whether two configs differ; with fewer
    than 2 pairs it is NaN (one difference has no spread)."""
    return contrast([(a, -1.0), (b, 1.0)], metric)


def clustered_sem(values, groups) -> float:
    """SEM of the mean of ``values`` when values of one group (episodes of one house) are
    correlated: the cluster-robust (CR1) standard error sqrt(G / (G - 1) * sum_g (S_g - n_g * m)^2) / n,
    with m the mean, S_g and n_g the sum and count of group g's values, G the number of groups
    and n the number of values. With one value per group it is the ordinary SEM; NaN with fewer
    than 2 groups (one house says nothing about the spread between houses)."""
    x = np.asarray(list(values), dtype=np.float64)
    labels = [str(g) for g in groups]
    if len(labels) != len(x):
        raise ValueError(f"clustered_sem: {len(x)} values but {len(labels)} group labels")
    names, code = np.unique(np.asarray(labels, dtype=str), return_inverse=True)
    g = len(names)
    if g < 2:
        return math.nan
    resid = np.bincount(code, weights=x - x.mean(), minlength=g)   # S_g - n_g * m per group
    return float(math.sqrt(g / (g - 1) * float(resid @ resid)) / len(x))


def jackknife_sem(leave_one_out) -> float:
    """Jackknife standard error of an estimate from its leave-one-group-out values theta_(g):
    sqrt((G - 1) / G * sum_g (theta_(g) - mean theta_(.))^2), for estimates that are no mean
    of independent values (a mIoU pools counts over houses). For the mean of G values it is their
    ordinary SEM; NaN with fewer than 2 groups."""
    x = np.asarray(list(leave_one_out), dtype=np.float64)
    g = len(x)
    if g < 2:
        return math.nan
    return float(math.sqrt((g - 1) / g * float(((x - x.mean()) ** 2).sum())))


def contrast_values(runs: list[tuple[list[dict], float]], metric: str) -> tuple[list[float], list[dict]]:
    """Per episode (matched by ``index``) that every run holds, sum_k w_k * ``metric``(run_k),
    each run's records with its weight ``w_k``, scored as ``paired_difference`` scores them;
    and the last run's record of each of those episodes (where its house is named)."""
    keep = is_finished if metric not in FAILURE_SCORED else (lambda r: True)
    scores = [{r["index"]: scored(r) for r in recs if "index" in r and keep(r)} for recs, _ in runs]
    shared = [i for i in scores[-1] if all(i in s for s in scores)] if scores else []
    values = [sum(w * float(s[i][metric]) for s, (_, w) in zip(scores, runs)) for i in shared]
    return values, [scores[-1][i] for i in shared]


def contrast(runs: list[tuple[list[dict], float]], metric: str) -> tuple[float, float, int]:
    """Mean and SEM over episodes of sum_k w_k * ``metric``(run_k), each run's records with its
    weight ``w_k``, over the episodes (matched by ``index``) every run holds, scored as
    ``paired_difference`` scores them (two runs weighted -1, +1 are that difference; four
    weighted +1, -1, -1, +1 are a difference of differences). Returns the mean, the SEM (NaN
    with fewer than 2 episodes) and the number of episodes."""
    return _contrast_of(contrast_values(runs, metric)[0])


def _contrast_of(values: list[float]) -> tuple[float, float, int]:
    m, sem = mean_sem(values)
    return m, (sem if len(values) >= 2 else math.nan), len(values)


HOUSE_KEY = "scene"   # the record key naming an episode's house: episodes of one house are correlated


def house_sem(runs: list[tuple[list[dict], float]], metric: str) -> float:
    """``clustered_sem`` of ``contrast``'s per-episode values, clustered by house (the records'
    ``HOUSE_KEY``); NaN when a record names no house or fewer than 2 houses hold the episodes."""
    return _house_sem_of(*contrast_values(runs, metric))


def _house_sem_of(values: list[float], recs: list[dict]) -> float:
    if not values or any(HOUSE_KEY not in r for r in recs):
        return math.nan
    return clustered_sem(values, [r[HOUSE_KEY] for r in recs])


def contrast_and_house_sem(runs: list[tuple[list[dict], float]], metric: str) -> tuple[float, float, int, float]:
    """``contrast`` and ``house_sem`` of the same runs and metric, the records scored once:
    (mean, SEM, N, house SEM)."""
    values, recs = contrast_values(runs, metric)
    return (*_contrast_of(values), _house_sem_of(values, recs))


def governing_sem(sem: float, by_house: float) -> float:
    """The SEM a difference is judged by: the larger of the episode SEM and the house SEM
    (``house_sem``: a house's episodes are correlated, so the episode SEM alone can be too
    small); the episode SEM where the house SEM is not defined (fewer than 2 houses, or records
    that name no house)."""
    return max(sem, by_house) if math.isfinite(by_house) else sem


LINGER_STEPS = 20   # an episode "lingered" when it stood at the goal, in view, longer than this without STOP


STOPPED_SHORT_M = 1.0        # a failed STOP within this distance of a view point found the object but stopped short, metres
STUCK_PATH_SHARE = 0.25      # out of steps having walked less than this share of what its forward steps allow: stuck
FAILURES: tuple[tuple[str, str], ...] = (
    ("false_stop", "False STOP"), ("stopped_short", f"Stopped short (< {STOPPED_SHORT_M:g} m)"),
    ("searching", "Out of steps, searching"), ("stuck", "Out of steps, stuck"), ("crashed", "Crashed"))
# failure_modes' coarse kinds: a STOP away from the goal, the step limit, a crash
COARSE_FAILURE = {"false_stop": "false_stop", "stopped_short": "false_stop", "searching": "timeout",
                  "stuck": "timeout", "crashed": "crashed"}


def failure_kind(record: dict, max_steps: int, forward_step_m: float) -> str | None:
    """How an episode failed (None: it succeeded), each failure in exactly one kind:
    ``crashed`` (an error record, ``finite_or_error``); STOP called before the step limit away
    from the goal -- ``stopped_short`` within STOPPED_SHORT_M of a view point (DistanceToGoal),
    else ``false_stop``; at ``max_steps`` actions (the agent's forced last STOP is no decision)
    -- ``stuck`` when its path is below STUCK_PATH_SHARE of ``steps * forward_step_m`` (blocked
    or turning in place), else ``searching``."""
    r = finite_or_error(record)
    if r.get("status", "ok") != "ok":
        return "crashed"
    if r.get("success"):
        return None
    if r.get("steps", 0) < max_steps:
        return "stopped_short" if r["distance_to_goal"] <= STOPPED_SHORT_M else "false_stop"
    walked = float(r.get("path_length", 0.0)) / max(1e-9, r["steps"] * forward_step_m)
    return "stuck" if walked < STUCK_PATH_SHARE else "searching"


def failure_modes(records: list[dict], max_steps: int) -> dict[str, int]:
    """Counts of how episodes failed, ``failure_kind`` coarsened (``COARSE_FAILURE``):
    ``false_stop`` (STOP called away from the goal before the step limit), ``timeout`` (still
    searching at ``max_steps`` actions) and ``crashed``; and, failed or not, ``lingered``:
    episodes whose agent stood where STOP would have succeeded, the goal in view, for more than
    LINGER_STEPS consecutive steps without calling it (records' ``steps_at_goal``; older records
    without it count 0)."""
    out = {"false_stop": 0, "timeout": 0, "crashed": 0, "lingered": 0}
    for r in map(finite_or_error, records):
        kind = failure_kind(r, max_steps, forward_step_m=1.0)   # any step length: stuck and searching merge
        if kind is not None:
            out[COARSE_FAILURE[kind]] += 1
        if kind != "crashed":
            out["lingered"] += int(r.get("steps_at_goal", 0) > LINGER_STEPS)
    return out


def run_label(cfg) -> str:
    """The agent as a metrics table names it, with what it maps from, so a table of the default
    config (the ground-truth segmenter) is not read as the learned one's: 'peanut (gt +
    averaging)', 'peanut (learned_rgb + ndf)'; an agent without a semantic map (the oracle) by
    name alone. ``cfg``: a root ``Config``."""
    if cfg.run.agent != "peanut":
        return cfg.run.agent
    semantic_map = cfg.mapping.fusion if cfg.agent.map_type == "fused" else cfg.agent.map_type
    return f"{cfg.run.agent} ({cfg.agent.segmenter} + {semantic_map})"


def format_metrics_table(rows: list[tuple[str, dict]], first_header: str = "Run") -> str:
    """Markdown table: one row per (name, summary), each metric as 'mean (SEM)'."""
    header = f"| {first_header} | " + " | ".join(METRIC_LABELS[m] for m in METRICS) + " | N |"
    sep = "|" + "---|" * (len(METRICS) + 2)
    lines = [header, sep]
    for name, s in rows:
        cells = [mean_sem_cell(s, m) for m in METRICS]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {s['count']} |")
    return "\n".join(lines)


def mean_sem_cell(summary: dict, metric: str) -> str:
    """'mean (SEM)' of a summary's metric, '-' for a mean of no episodes (None)."""
    mean, sem = summary.get(metric), summary.get(f"{metric}_sem")
    if mean is None:
        return "-"
    return f"{mean:.3f} ({sem:.3f})"
