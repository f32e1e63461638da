"""`calnav report MANIFEST`: the study's results page, rendered from its manifest and records alone.

``<output>/results.md`` holds, for the rows that have run (``eval.objectnav.study``):

- the metrics table: per row the goal threshold it ran at and where it came from, Success, SPL,
  SoftSPL (fractions) and DTG (metres) as mean (SEM) over the evaluation episodes, and N;
- the paired differences the study names (``pairs``) and, for every row that takes another
  row's threshold, the row minus its condition's own tuned row (the threshold-transfer
  question), each with its paired SEM, ``|d| / SEM`` and the verdict: "resolved" at 2 SEM or
  more, else "not resolved at N episodes" -- no direction is claimed inside 2 SEM;
- the failure breakdown per row (``failure_kind``: false STOP, stopped short, out of steps
  searching or stuck, crashed) and the median collisions;
- the tuning grids: Success vs goal threshold on the tuning episodes, one curve per tuned row
  (``threshold_curves.png``, +-1 SEM), with the chosen point marked;
- the rows not run yet, by name.

Every number comes from the committed records (``episodes.jsonl``) the manifest names, scored as
``calnav objectnav`` scores them (``eval.stats``), so the page changes only when records do.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

from calnav.eval.config import ConfigError
from calnav.eval.results_dir import read_records
from calnav.eval.stats import METRIC_LABELS, finite_or_error, is_finished, mean_sem_cell, paired_difference, summarize

RESOLVED_SEM = 2.0     # a difference is claimed only at this many paired SEMs or more
TABLE_METRICS: tuple[str, ...] = ("success", "spl", "softspl", "distance_to_goal")
PAIRED_METRICS: tuple[str, ...] = ("success", "spl")
RESULTS_NAME, CURVES_NAME = "results.md", "threshold_curves.png"


def load_manifest(path: Path) -> dict:
    """The manifest at ``path``; a missing or unreadable one is a one-line ConfigError."""
    if not path.is_file():
        raise ConfigError(f"manifest {path} not found; give the manifest.json a `calnav study` wrote")
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"manifest {path} is not JSON ({exc}); rerun `calnav study` to rewrite it") from None
    if not isinstance(manifest, dict) or not isinstance(manifest.get("rows"), dict):
        raise ConfigError(f"manifest {path} holds no rows; give the manifest.json a `calnav study` wrote")
    return manifest


def _eval_range(manifest: dict) -> range:
    a, _, b = str(manifest["evaluate"]["episodes"]).partition(":")
    return range(int(a), int(b)) if b else range(0, int(a))


def row_records(root: Path, manifest: dict) -> dict[str, list[dict]]:
    """{row name: its evaluation records, in index order} for every row that has run (a row
    that is the ``same_as`` another reads that row's records)."""
    wanted, out = set(_eval_range(manifest)), {}
    for name, entry in manifest["rows"].items():
        if entry.get("status") != "done":
            continue
        path = root / entry["dir"] / "episodes.jsonl"
        if not path.is_file():
            raise ConfigError(f"row {name}: records {path} not found (the manifest names them); copy the study's "
                              "eval/ directories with its manifest")
        recs = read_records(path, quiet=True).records
        out[name] = [recs[i] for i in sorted(recs) if i in wanted]
    return out


def transfer_pairs(manifest: dict) -> list[tuple[str, str]]:
    """[row, its condition's own tuned row] for every row that takes another row's threshold
    and has a tuned row with the same overrides."""
    rows = manifest["rows"]
    out = []
    for name, e in rows.items():
        if e.get("threshold_from"):
            own = next((n for n, o in rows.items() if not o.get("threshold_from") and o["overrides"] == e["overrides"]),
                       None)
            if own is not None:
                out.append((name, own))
    return out


def verdict(d: float, sem: float, n: int) -> str:
    """'resolved' when |d| >= RESOLVED_SEM paired SEMs, else 'not resolved at n episodes'."""
    if not (math.isfinite(d) and math.isfinite(sem)):
        return f"not resolved at {n} episodes"
    if sem == 0:
        return "identical on every episode" if d == 0 else "resolved"
    return "resolved" if abs(d) >= RESOLVED_SEM * sem else f"not resolved at {n} episodes"


def metrics_markdown(manifest: dict, records: dict[str, list[dict]]) -> str:
    lines = ["| Row | Threshold | " + " | ".join(f"{METRIC_LABELS[m]}" + (" (m)" if m == "distance_to_goal" else "")
                                               for m in TABLE_METRICS) + " | N |",
             "|" + "---|" * (len(TABLE_METRICS) + 3)]
    for name, recs in records.items():
        e, s = manifest["rows"][name], summarize(recs)
        source = f" ({e['threshold_from']})" if e.get("threshold_from") else ""
        lines.append(f"| {name} | {e['threshold']:g}{source} | " + " | ".join(mean_sem_cell(s, m) for m in TABLE_METRICS)
                     + f" | {s['count']} |")
    return "\n".join(lines)


def paired_markdown(pairs: list[tuple[str, str]], records: dict[str, list[dict]]) -> str:
    heads = ["Row", "minus"] + [f"d{METRIC_LABELS[m]} (SEM)" for m in PAIRED_METRICS] + \
            ["abs dSuccess / SEM", "Success verdict", "N paired"]
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    ready = [(a, b) for a, b in pairs if a in records and b in records]
    if not ready:
        return "None yet: no pair has both rows evaluated."
    for a, b in ready:
        cells = [a, b]
        first = None
        for m in PAIRED_METRICS:
            d, sem, n = paired_difference(records[b], records[a], m)
            first = first or (d, sem, n)
            cells.append(f"{d:+.3f} ({sem:.3f})" if math.isfinite(sem) else f"{d:+.3f} (-)")
        d, sem, n = first
        cells += [f"{abs(d) / sem:.1f}" if math.isfinite(sem) and sem > 0 else "-", verdict(d, sem, n), str(n)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


STOPPED_SHORT_M = 1.0        # a failed STOP within this distance of a view point found the object but stopped short, metres
STUCK_PATH_SHARE = 0.25      # out of steps having walked less than this share of what its forward steps allow: stuck
FAILURES: tuple[tuple[str, str], ...] = (
    ("false_stop", "False STOP"), ("stopped_short", f"Stopped short (< {STOPPED_SHORT_M:g} m)"),
    ("searching", "Out of steps, searching"), ("stuck", "Out of steps, stuck"), ("crashed", "Crashed"))


def failure_kind(record: dict, max_steps: int, forward_step_m: float) -> str | None:
    """How an episode failed (None: it succeeded), each failure in exactly one kind:
    ``crashed`` (an error record); STOP called before the step limit away from the goal --
    ``stopped_short`` within STOPPED_SHORT_M of a view point (DistanceToGoal), else
    ``false_stop``; at the step limit -- ``stuck`` when its path is below STUCK_PATH_SHARE of
    ``steps * forward_step_m`` (blocked or turning in place), else ``searching``."""
    r = finite_or_error(record)
    if r.get("status", "ok") != "ok":
        return "crashed"
    if r.get("success"):
        return None
    if r.get("steps", 0) < max_steps:
        return "stopped_short" if r["distance_to_goal"] <= STOPPED_SHORT_M else "false_stop"
    walked = float(r.get("path_length", 0.0)) / max(1e-9, r["steps"] * forward_step_m)
    return "stuck" if walked < STUCK_PATH_SHARE else "searching"


def failures_table(manifest: dict, records: dict[str, list[dict]]) -> str:
    """Per row: episodes failed, by kind (``failure_kind``), and the median collisions."""
    import statistics

    from calnav.envs.config import EnvConfig

    default = EnvConfig()
    lines = ["| Row | Failed | " + " | ".join(label for _, label in FAILURES) + " | Median collisions | N |",
             "|" + "---|" * (len(FAILURES) + 4)]
    for name, recs in records.items():
        env = manifest["rows"][name].get("config", {}).get("env", {})
        kinds = [failure_kind(r, int(env.get("max_episode_steps", default.max_episode_steps)),
                              float(env.get("forward_step_m", default.forward_step_m))) for r in recs]
        hits = [r["collisions"] for r in recs if is_finished(r) and "collisions" in r]
        median = f"{statistics.median(hits):g}" if hits else "-"
        lines.append(f"| {name} | {sum(k is not None for k in kinds)} | "
                     + " | ".join(str(kinds.count(k)) for k, _ in FAILURES) + f" | {median} | {len(recs)} |")
    return "\n".join(lines)


def plot_curves(manifest: dict, path: Path) -> Path | None:
    """Success vs goal threshold on the tuning episodes, one line per tuned row (+-1 SEM), the
    chosen point circled; None when no row has tuned yet."""
    tuned = {n: e["tune"] for n, e in manifest["rows"].items() if e.get("tune") and not e.get("threshold_from")}
    if not tuned:
        return None
    from calnav.eval.objectnav.report import _plt

    plt = _plt()
    groups = sorted({n.rsplit("/", 1)[0] for n in tuned})
    fig, axes = plt.subplots(1, len(groups), figsize=(4.2 * len(groups), 3.4), squeeze=False, sharey=True)
    for ax, group in zip(axes[0], groups):
        for n, t in tuned.items():
            if n.rsplit("/", 1)[0] != group:
                continue
            grid = sorted(t["grid"], key=lambda r: r["threshold"])
            line = ax.errorbar([r["threshold"] for r in grid], [r["success"] for r in grid],
                               yerr=[r["success_sem"] for r in grid], marker=".", capsize=3, label=n.rsplit("/", 1)[1])
            best = next(r for r in grid if r["threshold"] == t["threshold"])
            ax.plot([best["threshold"]], [best["success"]], "o", mfc="none", ms=10, color=line[0].get_color())
        ax.set_title(group, fontsize=9)
        ax.set_xlabel("goal threshold")
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel(f"Success on {manifest['tune']['split']} {manifest['tune']['episodes']} (+-1 SEM)")
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def render(manifest_path: Path) -> str:
    """The results page (Markdown) of the manifest at ``manifest_path``."""
    manifest = load_manifest(manifest_path)
    records = row_records(manifest_path.parent, manifest)
    ev, tune = manifest["evaluate"], manifest["tune"]
    pending = [n for n, e in manifest["rows"].items() if e.get("status") == "pending"]
    tuned = [(n, e["threshold"]) for n, e in manifest["rows"].items() if e.get("status") == "tuned"]
    skipped = [(n, e.get("reason", "")) for n, e in manifest["rows"].items() if e.get("status") == "skipped"]
    seconds = sum(float(e.get("episode_seconds", 0)) for e in manifest["rows"].values() if e.get("status") == "done")
    parts = [f"Evaluation: {ev['split']} episodes {ev['episodes']}, every row on the same episodes (paired). "
             f"Goal thresholds tuned on {tune['split']} {tune['episodes']} by {tune['metric']} "
             f"(grid {', '.join(f'{t:g}' for t in tune['thresholds'])}). Mean (SEM) over episodes; "
             f"evaluation compute {seconds / 3600:.2f} worker-hours.", "", metrics_markdown(manifest, records), ""]
    pairs = [tuple(p) for p in manifest.get("pairs", [])]
    parts += ["Paired differences (row minus the other, on the episodes both hold); a difference is claimed "
              f"only at {RESOLVED_SEM:g} SEM or more:", "", paired_markdown(pairs, records), ""]
    transfer = transfer_pairs(manifest)
    if transfer:
        parts += ["Threshold transfer: each row at another condition's tuned threshold minus the same row at its "
                  "own tuned threshold:", "", paired_markdown(transfer, records), ""]
    parts += ["Failures:", "", failures_table(manifest, records), ""]
    if skipped:
        parts += ["Skipped: " + "; ".join(f"{n} ({r})" for n, r in skipped) + ".", ""]
    if tuned:
        parts += ["Tuned, not evaluated yet: " + ", ".join(f"{n} (threshold {t:g})" for n, t in tuned) + ".", ""]
    if pending:
        parts += ["Not run yet: " + ", ".join(pending) + ".", ""]
    return "\n".join(parts)


def main_report(args, configs=()) -> None:
    manifest_path = Path(args.manifest)
    out = Path(args.output) if args.output else manifest_path.parent
    text = render(manifest_path)
    out.mkdir(parents=True, exist_ok=True)
    (out / RESULTS_NAME).write_text(text, encoding="utf-8")
    figure = plot_curves(load_manifest(manifest_path), out / CURVES_NAME)
    print(text)
    print(f"report: {out / RESULTS_NAME}" + (f", {figure}" if figure else ""))
