"""Summary statistics of episode results: mean and standard error of the mean (SEM)."""
from __future__ import annotations

import math

import numpy as np

METRICS: tuple[str, ...] = ("success", "spl", "softspl", "distance_to_goal")
METRIC_LABELS: dict[str, str] = {"success": "Success", "spl": "SPL", "softspl": "SoftSPL",
                                 "distance_to_goal": "DTG"}


def mean_sem(values) -> tuple[float, float]:
    """Mean and SEM = sample std (ddof=1) / sqrt(n); SEM is 0 for n = 1, NaN for n = 0."""
    x = np.asarray(list(values), dtype=np.float64)
    if len(x) == 0:
        return math.nan, math.nan
    if len(x) == 1:
        return float(x[0]), 0.0
    return float(x.mean()), float(x.std(ddof=1) / math.sqrt(len(x)))


def summarize(records: list[dict]) -> dict:
    """Episode records -> {metric: mean, metric_sem: SEM, count, failed, per_category: {...}}.
    Records with ``status != "ok"`` (crashed episodes) count as failures with Success/SPL 0
    and are reported in ``failed``."""
    ok = [r for r in records if r.get("status", "ok") == "ok"]
    out: dict = {"count": len(records), "failed": len(records) - len(ok)}
    rows = [scored(r) for r in records]
    for m in METRICS:
        vals = [r[m] for r in rows if r.get(m) is not None and math.isfinite(r[m])]
        out[m], out[f"{m}_sem"] = mean_sem(vals)
    per_cat: dict[str, dict] = {}
    for cat in sorted({r["category"] for r in records if "category" in r}):
        sub = [r for r in rows if r.get("category") == cat]
        per_cat[cat] = {"count": len(sub)}
        for m in METRICS:
            vals = [r[m] for r in sub if r.get(m) is not None and math.isfinite(r[m])]
            per_cat[cat][m], per_cat[cat][f"{m}_sem"] = mean_sem(vals)
    out["per_category"] = per_cat
    return out


def scored(record: dict) -> dict:
    """The record as it is scored: a crashed episode (``status != "ok"``) counts as a failure
    (Success, SPL, SoftSPL 0)."""
    if record.get("status", "ok") == "ok":
        return record
    return {**record, "success": 0.0, "spl": 0.0, "softspl": 0.0}


def paired_difference(a: list[dict], b: list[dict], metric: str) -> tuple[float, float, int]:
    """Mean and SEM of ``metric``(b) - ``metric``(a) over the episodes (matched by ``index``)
    both record lists hold, and their count. Pairing removes the episode-difficulty variance
    both runs share, so this SEM is the one that says whether two configs differ."""
    va = {r["index"]: scored(r).get(metric) for r in a if "index" in r}
    diffs = []
    for r in b:
        x, y = va.get(r.get("index")), scored(r).get(metric)
        if x is not None and y is not None and math.isfinite(x) and math.isfinite(y):
            diffs.append(y - x)
    m, sem = mean_sem(diffs)
    return m, sem, len(diffs)


LINGER_STEPS = 20   # an episode "lingered" when it stood at the goal, in view, longer than this without STOP


def failure_modes(records: list[dict], max_steps: int) -> dict[str, int]:
    """Counts of how episodes failed: ``false_stop`` (STOP called away from the goal before the
    step limit), ``timeout`` (still searching at ``max_steps`` actions; the agent's forced last
    STOP does not make it a decision) and ``crashed`` (``status != "ok"``); and, failed or not,
    ``lingered``: episodes whose agent stood where STOP would have succeeded, the goal in view,
    for more than LINGER_STEPS consecutive steps without calling it (records' ``steps_at_goal``;
    older records without it count 0)."""
    out = {"false_stop": 0, "timeout": 0, "crashed": 0, "lingered": 0}
    for r in records:
        if r.get("status", "ok") != "ok":
            out["crashed"] += 1
            continue
        if not r.get("success"):
            out["timeout" if r.get("steps", 0) >= max_steps else "false_stop"] += 1
        out["lingered"] += int(r.get("steps_at_goal", 0) > LINGER_STEPS)
    return out


def format_metrics_table(rows: list[tuple[str, dict]], first_header: str = "Run") -> str:
    """Markdown table: one row per (name, summary), each metric as 'mean (SEM)'."""
    header = f"| {first_header} | " + " | ".join(METRIC_LABELS[m] for m in METRICS) + " | N |"
    sep = "|" + "---|" * (len(METRICS) + 2)
    lines = [header, sep]
    for name, s in rows:
        cells = [f"{s[m]:.3f} ({s[m + '_sem']:.3f})" for m in METRICS]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {s['count']} |")
    return "\n".join(lines)
