"""What the study's records hold and cost, for ``calnav report``: the episodes a row runs, the
compute spent and still needed, the rows left out, and the source commits of the records.

Read from the manifest and the committed records alone (``eval.objectnav.study_report``).
"""
from __future__ import annotations

from pathlib import Path

from calnav.eval.objectnav.study import UNRECORDED_COMMIT, manifest_range, record_commits
from calnav.eval.results_dir import read_records


def eval_range(manifest: dict) -> range:
    return manifest_range(manifest["evaluate"]["episodes"])


def row_episodes(manifest: dict, entry: dict) -> int:
    """The evaluation episodes a row runs: the study's, but those its episode file's episodes
    calnav refuses (``summary.refused``: never run, so never missing)."""
    refused = ((entry.get("summary") or {}).get("refused") or {}).get("episodes", 0)
    return len(eval_range(manifest)) - int(refused)


def _records_cost(path: Path) -> tuple[int, float]:
    """(finished episodes, their summed wall_time_s) of a records file (0, 0 when absent)."""
    if not path.is_file():
        return 0, 0.0
    recs = read_records(path, quiet=True).records.values()
    return len(recs), sum(float(r.get("wall_time_s") or 0.0) for r in recs)


def evaluated(root: Path, name: str) -> int:
    """Episodes row ``name``'s evaluation has recorded so far under ``root/eval``."""
    return _records_cost(root / "eval" / name / "episodes.jsonl")[0]


def compute_markdown(root: Path, manifest: dict) -> str:
    """Episodes run and worker-hours (the records' wall_time_s: one worker per core) for tuning
    and evaluation, and the episodes the plan still needs (a tuned row's grid before any
    extension, each evaluation not shared with an earlier row) with the worker-hours they take at
    the mean cost per episode so far; the same for the rows the study leaves out."""
    tune_n = tune_s = eval_n = eval_s = 0.0
    left = cut = 0
    per_tune = len(manifest_range(manifest["tune"]["episodes"]))
    n_eval = len(eval_range(manifest))
    areas = len(manifest["tune"].get("min_areas", [4]))
    for name, e in manifest["rows"].items():
        grid = len(e.get("thresholds") or manifest["tune"]["thresholds"]) * areas   # a row may name its own grid
        if not e.get("threshold_from"):
            n = s = 0
            for f in sorted((root / "tune" / name).glob("*/episodes.jsonl")):
                fn, fs = _records_cost(f)
                n, s = n + fn, s + fs
            tune_n, tune_s = tune_n + n, tune_s + s
            if e.get("status") == "pending":
                left += max(0, grid * per_tune - n)
            elif e.get("status") == "left_out":
                cut += max(0, grid * per_tune - n)
        if e.get("status") == "done" and not e.get("same_as"):
            n, s = _records_cost(root / e["dir"] / "episodes.jsonl")
            eval_n, eval_s = eval_n + n, eval_s + s
            left += max(0, row_episodes(manifest, e) - n)   # a finished row short of episodes is not run
        elif e.get("status") in ("pending", "tuned"):
            left += max(0, n_eval - evaluated(root, name))
        elif e.get("status") == "left_out":   # what its evaluation ran before it was left out counts as run
            n, s = _records_cost(root / "eval" / name / "episodes.jsonl")
            eval_n, eval_s, cut = eval_n + n, eval_s + s, cut + max(0, n_eval - n)
    done_n, done_s = tune_n + eval_n, tune_s + eval_s
    per_ep = done_s / done_n if done_n else float("nan")
    return (f"Compute so far: {int(tune_n)} tuning episodes ({tune_s / 3600:.1f} worker-hours) and {int(eval_n)} "
            f"evaluation episodes ({eval_s / 3600:.1f} worker-hours), {per_ep:.2f} s per episode on one core; "
            f"on the 2-core development machine (2 workers) that is about {done_s / 7200:.1f} hours of wall time. "
            + (f"The plan still needs about {left} episodes ({left * per_ep / 3600:.1f} worker-hours, about "
               f"{left * per_ep / 7200:.1f} hours on 2 cores), counting each tuning grid before any extension."
               if left else "Every row the study runs has run.")
            + (f" The rows the study leaves out would need about {cut} more ({cut * per_ep / 3600:.1f} worker-hours, "
               f"about {cut * per_ep / 7200:.1f} hours on 2 cores)." if cut else ""))


def left_out_markdown(root: Path, manifest: dict) -> str:
    """The rows the study file leaves out (``left_out``), grouped by the reason it gives, each
    with the episodes its evaluation ran before it was left out, if any; "" when it leaves out
    none."""
    groups: dict[str, list[str]] = {}
    wanted = len(eval_range(manifest))
    for name, e in manifest["rows"].items():
        if e.get("status") == "left_out":
            ran = evaluated(root, name)
            groups.setdefault(e.get("reason", ""), []).append(
                f"{name} ({ran} of {wanted} episodes evaluated)" if ran else name)
    return " ".join(f"Left out ({reason.rstrip('.')}): {', '.join(names)}." for reason, names in groups.items())


def commits_markdown(records: dict[str, list[dict]]) -> str:
    """Which source commit ran how many of each row's evaluation records (every record names
    its commit; older records count as ``unrecorded``), rows with the same commits on one line."""
    groups: dict[tuple, list[str]] = {}
    for name, recs in records.items():
        groups.setdefault(tuple(record_commits(recs).items()), []).append(name)
    lines = [f"- {', '.join(f'`{c[:7]}` ({n})' if c != UNRECORDED_COMMIT else f'{c} ({n})' for c, n in key)}: "
             + ", ".join(names) for key, names in groups.items()]
    return "Source commits of the evaluation records (episodes each):\n\n" + "\n".join(lines)
