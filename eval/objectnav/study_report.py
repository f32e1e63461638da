"""`calnav report MANIFEST`: the study's results page, rendered from its manifest and records alone.

``<output>/results.md`` holds, for the rows that have run (``eval.objectnav.study``):

- the metrics table: per row the goal threshold it ran at and where it came from, Success, SPL,
  SoftSPL (fractions) and DTG (metres) as mean (SEM) over the evaluation episodes, and N;
- the paired differences the study names (``pairs``) and, for every row that takes another
  row's threshold, the row minus its condition's own tuned row (the threshold-transfer
  question), each with its paired SEM over episodes and its SEM clustered by house
  (``eval.stats.house_sem``: a house's episodes are correlated), ``|d|`` over the larger of the
  two and the verdict: "resolved" at 2 of the larger SEM or more, else "not resolved at N
  episodes" -- no direction is claimed inside 2 SEM;
- the failure breakdown per row (``eval.stats.failure_kind``: false STOP, stopped short, out of steps
  searching or stuck, crashed) and the median collisions;
- the tuning grids (``eval.objectnav.study_grids``): Success vs goal threshold on the tuning
  episodes per tuned row, as a table and a figure (``threshold_curves.png``, +-1 SEM) with the
  chosen point marked, and the rows whose best threshold still sits on an edge of their
  extended grid;
- the source commits that ran each row's records (each record names its commit);
- the rows tuned but not fully evaluated (with the episodes evaluated so far), the rows not
  run yet, by name, and the rows the study file leaves out, with its reason and what they would
  cost.

Every number comes from the committed records (``episodes.jsonl``) the manifest names, scored as
``calnav objectnav`` scores them (``eval.stats``), so the page changes only when records do.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

from calnav.eval.config import ConfigError
from calnav.eval.objectnav.study import manifest_row_records
from calnav.eval.objectnav.study_grids import edge_rows, grids_markdown, plot_curves, transfer_pairs
from calnav.eval.objectnav.study_ledger import (eval_range, evaluated, commits_markdown, compute_markdown,
                                                left_out_markdown, row_episodes)
from calnav.eval.stats import (FAILURES, METRIC_LABELS, contrast_and_house_sem, failure_kind, governing_sem,
                               is_finished, mean_sem_cell, same_episode, summarize)
from dataclasses import dataclass
from calnav.eval.arguments import REQUIRED, Command, arg

RESOLVED_SEM = 2.0     # a difference is claimed only at this many paired SEMs or more (the larger of episode and house SEM)
TABLE_METRICS: tuple[str, ...] = ("success", "spl", "softspl", "distance_to_goal")
PAIRED_METRICS: tuple[str, ...] = ("success", "spl")
CLAIM = (f"a direction is claimed only at {RESOLVED_SEM:g} SEM or more, judged by the larger of the episode SEM "
         "and the house SEM (clustered by house: a house's episodes are correlated)")
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


def row_records(manifest_path: Path, manifest: dict) -> dict[str, list[dict]]:
    """{row name: its evaluation records, in index order} for every row that has run (a row
    that is the ``same_as`` another reads that row's records), each checked against what the
    manifest says of it (``eval.objectnav.study.manifest_row_records``)."""
    return {name: manifest_row_records(manifest_path, manifest, name)
            for name, entry in manifest["rows"].items() if entry.get("status") == "done"}


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
    heads = ["Row", "minus"] + [f"d{METRIC_LABELS[m]} (SEM, house SEM)" for m in PAIRED_METRICS] + \
            ["abs dSuccess / larger SEM", "Success verdict", "N paired"]
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    ready = [(a, b) for a, b in pairs if a in records and b in records]
    if not ready:
        return "None yet: no pair has both rows evaluated."
    for a, b in ready:
        lines.append("| " + " | ".join([a, b, *contrast_cells([a, b], [1.0, -1.0], records)]) + " |")
    return "\n".join(lines)


def _sem_text(sem: float) -> str:
    return f"{sem:.3f}" if math.isfinite(sem) else "-"


def contrast_cells(names: list[str], weights: list[float], records: dict[str, list[dict]]) -> list[str]:
    """The table cells of a contrast of rows (``eval.stats.contrast``, paired over the episodes
    they share, checked to be the same ones): per PAIRED_METRICS "d (SEM, house SEM)", then
    |dSuccess| / the larger SEM (``governing_sem``), the Success verdict and N."""
    check_same_episodes(names, records)
    runs = [(records[n], float(w)) for n, w in zip(names, weights)]
    cells, first = [], None
    for m in PAIRED_METRICS:
        d, sem, n, by_house = contrast_and_house_sem(runs, m)   # the runs' records scored once per metric
        first = first or (d, governing_sem(sem, by_house), n)
        cells.append(f"{d:+.3f} ({_sem_text(sem)}, {_sem_text(by_house)})")
    d, sem, n = first
    return [*cells, _ratio(d, sem), verdict(d, sem, n), str(n)]


def conclusions_markdown(manifest: dict, records: dict[str, list[dict]]) -> str:
    """The study's questions (``StudyQuestion``), each answered by its contrast of rows' Success
    and SPL over the episodes its rows share, with the verdict on Success; a question whose rows
    have not all run says which it waits for, and one naming a row the study leaves out says it is
    not answered."""
    questions = manifest.get("questions") or []
    if not questions:
        return "The study file asks no questions."
    heads = ["Question", "Contrast"] + [f"{METRIC_LABELS[m]} (SEM, house SEM)" for m in PAIRED_METRICS] + \
            ["abs / larger SEM", "Success verdict", "N"]
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    for q in questions:
        terms = " ".join(f"{'+' if w > 0 else '-'} {'' if abs(w) == 1 else f'{abs(w):g} '}{n}"
                         for n, w in zip(q["rows"], q["weights"])).removeprefix("+ ")
        cut = [n for n in q["rows"] if manifest["rows"].get(n, {}).get("status") == "left_out"]
        waiting = [n for n in q["rows"] if n not in records]
        if cut or waiting:
            why = f"not answered: the study leaves out {', '.join(cut)}" if cut else f"waiting for {', '.join(waiting)}"
            lines.append(f"| {q['ask']} | {terms} | {why} |" + " |" * (len(heads) - 3))
            continue
        lines.append("| " + " | ".join([q["ask"], terms, *contrast_cells(q["rows"], q["weights"], records)]) + " |")
    return "\n".join(lines)


def _ratio(d: float, sem: float) -> str:
    """|d| / SEM, rounded down to 2 decimals: 1.996 must not read as the 2.0 that resolves."""
    return f"{math.floor(100 * abs(d) / sem) / 100:.2f}" if math.isfinite(sem) and sem > 0 else "-"


def check_same_episodes(names: list[str], records: dict[str, list[dict]]) -> None:
    """Refuse (ConfigError) a paired comparison of rows that share no episode index, or whose
    records at a shared index are different episodes (``eval.stats.same_episode``: another
    house style reuses the indices): any number printed for it would be made up."""
    first = {r["index"]: r for r in records[names[0]] if "index" in r}
    for name in names[1:]:
        other = {r["index"]: r for r in records[name] if "index" in r}
        shared = first.keys() & other.keys()
        if not shared:
            raise ConfigError(f"rows {names[0]} and {name} share no evaluation episode; a paired comparison needs "
                              "the same episodes")
        bad = next((i for i in sorted(shared) if not same_episode(first[i], other[i])), None)
        if bad is not None:
            raise ConfigError(f"rows {names[0]} and {name} hold different episodes at index {bad} "
                              f"({first[bad].get('episode_id')} vs {other[bad].get('episode_id')}); a paired "
                              "comparison needs the same episodes (the same house style and dataset)")


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


def render(manifest_path: Path) -> str:
    """The results page (Markdown) of the manifest at ``manifest_path``."""
    manifest = load_manifest(manifest_path)
    records = row_records(manifest_path, manifest)
    ev, tune = manifest["evaluate"], manifest["tune"]
    pending = [n for n, e in manifest["rows"].items() if e.get("status") == "pending"]
    tuned = [(n, e["threshold"]) for n, e in manifest["rows"].items() if e.get("status") == "tuned"]
    skipped = [(n, e.get("reason", "")) for n, e in manifest["rows"].items() if e.get("status") == "skipped"]
    seconds = sum(float(e.get("episode_seconds", 0)) for e in manifest["rows"].values()   # a same_as row ran nothing
                  if e.get("status") == "done" and not e.get("same_as"))
    parts = [f"Evaluation: {ev['split']} episodes {ev['episodes']}, every row on the same episodes (paired). "
             f"Goal thresholds tuned on {tune['split']} {tune['episodes']} by {tune['metric']} "
             f"(grid {', '.join(f'{t:g}' for t in tune['thresholds'])}, extended by up to {tune.get('extend', 0)} "
             "thresholds past an edge the best one sits on; a row may name its own grid: the tuning grids below). "
             "Mean (SEM) over episodes; "
             f"evaluation compute {seconds / 3600:.2f} worker-hours.", "", metrics_markdown(manifest, records), ""]
    wanted = len(eval_range(manifest))
    short = [f"{n} ({len(r)} of {row_episodes(manifest, manifest['rows'][n])})" for n, r in records.items()
             if len(r) < row_episodes(manifest, manifest["rows"][n])]
    if short:   # a row finished short of its episodes: its row's N says so, and so does this line
        parts += ["Rows holding fewer records than the evaluation episodes (rerun `calnav study` to fill them): "
                  + ", ".join(short) + ".", ""]
    parts += [f"Conclusions: each question's contrast of rows on the episodes they share; {CLAIM}:", "",
              conclusions_markdown(manifest, records), ""]
    pairs = [tuple(p) for p in manifest.get("pairs", [])]
    parts += [f"Paired differences (row minus the other, on the episodes both hold); {CLAIM}:", "",
              paired_markdown(pairs, records), ""]
    transfer = transfer_pairs(manifest)
    if transfer:
        parts += ["Threshold transfer: each row at another condition's tuned threshold minus the same row at its "
                  "own tuned threshold:", "", paired_markdown(transfer, records), ""]
    parts += ["Failures:", "", failures_table(manifest, records), ""]
    grids = grids_markdown(manifest)
    if grids:
        parts += ["Tuning grids: Success against the goal threshold on the tuning episodes, per row that tunes its own "
                  "(+-1 SEM in the figure, the chosen point circled; a dotted line, crossed where it is on the grid, at each "
                  "threshold transferred from another condition):", "", grids, "",
                  f"![Success against the goal threshold, per tuned row]({CURVES_NAME})", ""]
    edges = edge_rows(manifest)
    if edges:
        parts += ["Tuned on an edge of the grid (the best threshold beats its neighbour after every extension, so "
                  "the optimum may lie beyond the grid): " + ", ".join(f"{n} ({t:g})" for n, t in edges) + ".", ""]
    parts += [compute_markdown(manifest_path.parent, manifest), ""]
    if records:
        parts += [commits_markdown(records), ""]
    if skipped:
        parts += ["Skipped: " + "; ".join(f"{n} ({r})" for n, r in skipped) + ".", ""]
    # rows whose evaluation has begun but not finished: a study stopped mid-row resumes from there
    ran = {n: evaluated(manifest_path.parent, n) for n in [*(n for n, _ in tuned), *pending]}
    started, unstarted = [n for n in pending if ran[n]], [n for n in pending if not ran[n]]
    if tuned:
        parts += ["Tuned, evaluation not finished: " + ", ".join(
            f"{n} (threshold {t:g}; {ran[n]} of {wanted} episodes evaluated)" for n, t in tuned) + ".", ""]
    if started:
        parts += ["Evaluation not finished: " + ", ".join(
            f"{n} ({ran[n]} of {wanted} episodes evaluated)" for n in started) + ".", ""]
    if unstarted:
        parts += ["Not run yet: " + ", ".join(unstarted) + ".", ""]
    cut = left_out_markdown(manifest_path.parent, manifest)
    if cut:
        parts += [cut, ""]
    return "\n".join(parts)


PAGE_BEGIN, PAGE_END = "<!-- calnav report -->", "<!-- /calnav report -->"


def headline(manifest_path: Path, page: Path, results: Path) -> str:
    """The headline a page embeds (README, the study page): the metrics table and the
    conclusions of the manifest at ``manifest_path``, with the command and a link to the full
    ``results`` page (relative to ``page``)."""
    import os

    manifest = load_manifest(manifest_path)
    records = row_records(manifest_path, manifest)
    ev, tune = manifest["evaluate"], manifest["tune"]
    done, total = len(records), len(manifest["rows"])
    left_out = sum(e.get("status") == "left_out" for e in manifest["rows"].values())
    link = Path(os.path.relpath(results.resolve(), page.resolve().parent)).as_posix()
    cut = left_out_markdown(manifest_path.parent, manifest)
    return "\n".join([
        f"Rendered by `calnav report {manifest_path.as_posix()}` from the study's committed records: "
        f"{done} of {total} rows evaluated on {ev['split']} episodes {ev['episodes']} (paired), each at the goal "
        f"threshold tuned on {tune['split']} {tune['episodes']}; mean (SEM)"
        f"{f'; the study leaves out {left_out} (below)' if left_out else ''}. Everything else -- paired "
        f"differences, threshold transfer, failures, the threshold curves, compute -- is in [the results page]({link}).",
        *(["", cut] if cut else []),
        "", metrics_markdown(manifest, records), "", f"Conclusions; {CLAIM}:", "",
        conclusions_markdown(manifest, records)])


def embed(page_text: str, block: str, page: Path) -> str:
    """``page_text`` with its ``PAGE_BEGIN`` ... ``PAGE_END`` block replaced by ``block``; a
    page without exactly one such block is a one-line ConfigError."""
    if page_text.count(PAGE_BEGIN) != 1 or page_text.count(PAGE_END) != 1 or \
            page_text.index(PAGE_BEGIN) > page_text.index(PAGE_END):
        raise ConfigError(f"--page {page}: needs one '{PAGE_BEGIN}' line and one '{PAGE_END}' line after it, "
                          "where the headline goes")
    head, rest = page_text.split(PAGE_BEGIN)
    return f"{head}{PAGE_BEGIN}\n{block}\n{PAGE_END}{rest.split(PAGE_END, 1)[1]}"


def main_report(args, configs=()) -> None:
    manifest_path = Path(args.manifest)
    out = Path(args.output) if args.output else manifest_path.parent
    text = render(manifest_path)
    pages = {}
    for name in getattr(args, "page", []):   # every page checked before anything is written
        page = Path(name)
        if not page.is_file():
            raise ConfigError(f"--page {page}: no such file; give a Markdown file holding a '{PAGE_BEGIN}' block")
        pages[page] = embed(page.read_text(encoding="utf-8"), headline(manifest_path, page, out / RESULTS_NAME), page)
    out.mkdir(parents=True, exist_ok=True)
    (out / RESULTS_NAME).write_text(text, encoding="utf-8")
    figure = plot_curves(load_manifest(manifest_path), out / CURVES_NAME)
    for page, page_text in pages.items():
        page.write_text(page_text, encoding="utf-8")
    print(text)
    print(f"report: {out / RESULTS_NAME}" + (f", {figure}" if figure else "")
          + "".join(f", {page}" for page in pages))


@dataclass
class ReportArgs:
    """``calnav report``'s flags."""

    manifest: str = arg(REQUIRED, "the manifest.json `calnav study` wrote", positional=True)
    output: str = arg("", "directory for results.md (default: the manifest's)")
    page: list[str] = arg([], "a Markdown file whose '<!-- calnav report -->' ... '<!-- /calnav report -->' block "
                              "becomes the headline (metrics table and conclusions); repeatable, e.g. README.md",
                          metavar="FILE", repeat=True)


COMMAND = Command(ReportArgs, main_report, sections=(), overrides=None)   # reads records
