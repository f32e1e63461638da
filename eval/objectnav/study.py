"""`calnav study CONFIG`: the ObjectNav study (tune each map's goal threshold on one split,
evaluate on held-out episodes of another), resumable, with a manifest of where every number
comes from.

The study config (``eval.objectnav.study_config``) lists rows in run order. For each row:

1. a tuned row runs ``calnav tune``'s grid (``run_tune``) on the tuning episodes into
   ``<output>/tune/<row>/`` (``tune.csv``, ``best.yaml``, a results directory per grid point);
2. the row is evaluated at its tuned point -- or at the tuned point of the row it names in
   ``threshold_from`` -- on the evaluation episodes into ``<output>/eval/<row>/``, a results
   directory like ``calnav objectnav``'s. A row whose evaluation config equals an earlier
   row's (a transferred threshold that equals the row's own) is not run twice: its manifest
   entry names the earlier records -- also when ``--rows`` leaves out the earlier row that an
   earlier invocation finished. A row whose config the tuned point makes invalid (the
   uncertainty-aware agent's band below a low tuned threshold) is skipped, with the reason.

A row the study file leaves out (``left_out: <why>``, e.g. the compute budget) runs nothing; the
manifest marks it ``left_out`` with the reason, and the report lists it.

Every step resumes: an interrupted study is continued by rerunning the same command. After each
row ``<output>/manifest.json`` is rewritten (atomically): the study file and its sha256, and
per row the equivalent single commands, the resolved config, the source commits that ran its
records and its tuning grid's (with how many each: every record names its commit), the sha256 of
every weight file (``inputs.json``) and episode file it read, the episode seconds it took, its
summary, and where its records are. ``calnav report`` renders the results pages from it.
"""
from __future__ import annotations

import gzip
import hashlib
import math
import shlex
from collections import Counter
from pathlib import Path

from calnav.eval.config import ConfigError, load_config, parse_override, to_dict
from calnav.eval.inputs import INPUTS_NAME, sha256_file
from calnav.eval.objectnav.study_config import StudyConfig, StudyRow, load_study
from calnav.eval.objectnav.tune import point_name, summary_row
from calnav.eval.results_dir import RECORDS_NAME, NEUTRAL_KEYS, ResultsDir, ResultsError, read_records, strip_neutral
from calnav.eval.stats import METRICS, summarize

MANIFEST_NAME = "manifest.json"
MANIFEST_VERSION = 1


def episode_files(env_cfg, upto: int) -> dict[str, str]:
    """{path under the calnav cache: sha256 of its JSON} of the cached episode files holding episodes
    ``0:upto`` of ``env_cfg.split`` (their scenes' ``content/<scene>.json.gz``)."""
    from calnav.envs.episodes import scenes_needed, split_dir
    from calnav.envs.scene import cache_dir

    needed, _ = scenes_needed(env_cfg.split, env_cfg, upto)
    root = split_dir(env_cfg.split, env_cfg) / "content"
    files = [root / f"{sid}.json.gz" for sid in needed]
    # the JSON inside is hashed: gzip's header holds the write time, so a regenerated file of the
    # same episodes would change a hash of the file itself
    return {str(f.relative_to(cache_dir())): hashlib.sha256(gzip.decompress(f.read_bytes())).hexdigest()
            for f in files if f.is_file()}


# what a record made before records carried their commit counts as
UNRECORDED_COMMIT = "unrecorded"


def _episode_seconds(records_path: Path, indices: range) -> tuple[int, float, dict[str, int]]:
    """(episodes recorded of ``indices``, the sum of their ``wall_time_s``: worker seconds,
    {commit: episodes}: which source commit ran how many of them -- a row resumed across
    commits lists each; records older than the ``commit`` field count as ``unrecorded``)."""
    if not records_path.is_file():
        return 0, 0.0, {}
    wanted = set(indices)
    recs = [r for r in read_records(records_path, quiet=True).records.values() if r.get("index") in wanted]
    return len(recs), float(sum(float(r.get("wall_time_s") or 0.0) for r in recs)), record_commits(recs)


def record_commits(records) -> dict[str, int]:
    """{commit: records it ran}, sorted; records older than the ``commit`` field: ``unrecorded``."""
    return dict(sorted(Counter(r.get("commit") or UNRECORDED_COMMIT for r in records).items()))


def _tune_commits(tune_dir: Path) -> dict[str, int]:
    """``record_commits`` over every grid point's records of a tuning directory."""
    return record_commits(r for path in sorted(tune_dir.glob("*/episodes.jsonl"))
                    for r in read_records(path, quiet=True).records.values())


def manifest_range(spec: str) -> range:
    """The episode indices of a manifest's episode range ('N' or 'A:B', as the study file gives it)."""
    a, _, b = str(spec).partition(":")
    return range(int(a), int(b)) if b else range(0, int(a))


# what a manifest's evaluation summary says that its records decide (manifest_row_records)
SUMMARY_FIELDS: tuple[str, ...] = ("count", "failed", *(f"{m}{s}" for m in METRICS for s in ("", "_sem")))
SECONDS_TOL = 5e-4   # episode_seconds is written rounded to the millisecond


def _differences(claimed: dict, actual: dict) -> list[str]:
    """'field claimed vs actual' for each field of ``actual`` that ``claimed`` holds and states
    otherwise (numbers within float round-off)."""
    def same(a, b) -> bool:
        if isinstance(a, (int, float)) and isinstance(b, (int, float)):
            return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)
        return a == b
    return [f"{k} {claimed[k]!r} where the records give {v!r}" for k, v in actual.items()
            if k in claimed and not same(claimed[k], v)]


def _disagreement(manifest_path: Path, row: str, what: str, path: Path, differences: list[str]) -> ResultsError:
    more = f" (and {len(differences) - 1} more field(s))" if len(differences) > 1 else ""
    return ResultsError(f"{manifest_path}: row {row}'s {what} disagrees with its records {path}: {differences[0]}{more}; "
                        f"the records are the results: rerun `calnav study` on the row (--rows {row}) to rewrite its "
                        "entry, or restore the records it was written from")


def manifest_row_records(manifest_path: Path, manifest: dict, row: str) -> list[dict]:
    """The evaluation records (in index order) of the finished (``done``) row ``row`` of the
    manifest ``manifest`` read from ``manifest_path``, read with ``read_records`` and checked
    against everything the manifest says of them: its ``episodes``, ``episode_seconds``,
    ``commits`` and ``summary`` (``SUMMARY_FIELDS``), and each tuning grid point's figures
    (``tune.grid``) against that point's records. ConfigError when the records are missing;
    ResultsError (one line, the first difference) when the manifest states what its records do
    not; a manifest entry without a field is not checked on it."""
    root, entry = manifest_path.parent, manifest["rows"][row]
    path = root / entry["dir"] / RECORDS_NAME
    if not path.is_file():
        raise ConfigError(f"row {row}: records {path} not found (the manifest names them); copy the study's "
                          "eval/ directories with its manifest")
    wanted = manifest_range(manifest["evaluate"]["episodes"])
    recs = read_records(path, quiet=True).records
    out = [recs[i] for i in sorted(recs) if i in wanted]
    summary = summarize(out)
    actual = {"episodes": len(out), "commits": record_commits(out),
              "episode_seconds": sum(float(r.get("wall_time_s") or 0.0) for r in out)}
    diffs = _differences(entry, {k: v for k, v in actual.items() if k != "episode_seconds"})
    if "episode_seconds" in entry and abs(float(entry["episode_seconds"]) - actual["episode_seconds"]) > SECONDS_TOL:
        diffs.append(f"episode_seconds {entry['episode_seconds']!r} where the records give "
                     f"{round(actual['episode_seconds'], 3)!r}")
    diffs += _differences(entry.get("summary") or {}, {k: summary[k] for k in SUMMARY_FIELDS})
    if diffs:
        raise _disagreement(manifest_path, row, "entry", path, diffs)
    tune = entry.get("tune") or {}
    if tune.get("dir"):
        tune_range = manifest_range(manifest["tune"]["episodes"])
        for point in tune.get("grid", []):
            t, a = point["threshold"], point["min_area"]
            tpath = root / tune["dir"] / point_name(t, a) / RECORDS_NAME
            trecs = read_records(tpath, quiet=True).records
            got = summary_row(t, a, summarize([trecs[i] for i in sorted(trecs) if i in tune_range]))
            diffs = _differences(point, got)
            if diffs:
                raise _disagreement(manifest_path, row, f"tuning grid point {point_name(t, a)}", tpath, diffs)
    return out


def _read_json(path: Path) -> dict | None:
    import json

    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None


def _tune_command(study: StudyConfig, row: StudyRow, extra: list[str], out: Path) -> str:
    t = study.tune
    return shlex.join(["calnav", "tune", "--config", study.config, "--episodes", t.episodes,
                       "--thresholds", ",".join(repr(v) for v in study.grid(row)),
                       "--min-areas", ",".join(map(str, t.min_areas)), "--extend", str(t.extend),
                       "--metric", t.metric, "--output", str(out), *study.tune_overrides(row, extra)])


def _eval_command(study: StudyConfig, out: Path) -> str:
    return shlex.join(["calnav", "objectnav", "--config", str(out / "config.yaml"),
                       "--episodes", study.evaluate.episodes, "--output", str(out)])


def _relevant(overrides: list[str]) -> list[str]:
    """The overrides that can change a result: all but those of the result-neutral keys
    (``eval.results_dir.NEUTRAL_KEYS``: workers, backend, output directory, ...)."""
    return [o for o in overrides if parse_override(o)[0] not in NEUTRAL_KEYS]


class Manifest:
    """``<output>/manifest.json``: the study's provenance, rewritten after every row."""

    def __init__(self, root: ResultsDir, study: StudyConfig, study_path: Path, extra: list[str]):
        self.root = root
        self.data = {"version": MANIFEST_VERSION, "study": str(study_path), "study_sha256": sha256_file(study_path),
                     "config": study.config, "overrides": list(extra), "tune": to_dict(study.tune), "evaluate": to_dict(study.evaluate),
                     "pairs": [list(p) for p in study.pairs], "questions": [to_dict(q) for q in study.questions],
                     "rows": {r.name: {"status": "left_out" if r.left_out else "pending",
                                       **({"reason": r.left_out} if r.left_out else {}),
                                       "overrides": study.row_overrides(r),
                                       "threshold_from": r.threshold_from, "thresholds": r.thresholds}
                              for r in study.rows}}

    def carry(self, previous: dict | None) -> None:
        """Keep the entries of an earlier invocation (``--rows`` runs some rows only) for rows
        whose overrides, threshold source and grid are unchanged, when the episodes, the base
        config and the command line's result-relevant overrides are the same; a row that runs now
        replaces its entry. A row the study leaves out now stays left out, and one it left out then
        but runs now starts pending (it resumes from its records)."""
        if not previous or previous.get("version") != MANIFEST_VERSION or \
                (previous.get("tune"), previous.get("evaluate")) != (self.data["tune"], self.data["evaluate"]) or \
                previous.get("config", self.data["config"]) != self.data["config"] or \
                _relevant(previous.get("overrides", [])) != _relevant(self.data["overrides"]):
            return
        for name, entry in previous.get("rows", {}).items():
            now = self.data["rows"].get(name)
            if now is not None and "left_out" not in (now["status"], entry.get("status")) and (entry.get("overrides"), entry.get("threshold_from"),
                                    entry.get("thresholds", now["thresholds"])) == \
                    (now["overrides"], now["threshold_from"], now["thresholds"]):
                self.data["rows"][name] = {**entry, "thresholds": now["thresholds"]}   # (older manifests lack it)

    def update(self, name: str, **entry) -> None:
        """Replace row ``name``'s entry (keeping its overrides and threshold source) and rewrite
        the manifest."""
        now = self.data["rows"][name]
        self.data["rows"][name] = {"overrides": now["overrides"], "threshold_from": now["threshold_from"],
                                   "thresholds": now["thresholds"], **entry}
        self.write()

    def write(self) -> None:
        self.root.write_json(MANIFEST_NAME, self.data)


def run_study(study_path: str | Path, out: Path, extra: list[str] = (), force: bool = False,
              progress: bool = True, only: tuple[str, ...] = ()) -> dict:
    """Run (or resume) the study at ``study_path`` into ``out``; returns the manifest dict.
    ``extra``: overrides of every row (the command line's); ``only``: run just these rows (and
    the tuning of the rows they take a threshold from)."""
    from calnav.eval.episodes import episode_indices
    from calnav.eval.objectnav.run import EpisodeJob, run_jobs
    from calnav.eval.objectnav.tune import run_tune

    study_path, out, extra = Path(study_path), Path(out), list(extra)
    study, _ = load_study(study_path, extra)
    unknown = [n for n in only if n not in {r.name for r in study.rows}]
    if unknown:
        raise ConfigError(f"--rows: no row {unknown[0]!r} in {study_path}; rows: {', '.join(r.name for r in study.rows)}")
    left_out = [n for n in only if study.row(n).left_out]
    if left_out:
        raise ConfigError(f"--rows: {left_out[0]} is left out by {study_path} ({study.row(left_out[0]).left_out}); "
                          "remove its left_out key to run it")
    wanted = set(only) | {study.row(n).threshold_from for n in only if study.row(n).threshold_from} if only else None
    tuned: dict[str, dict] = {}
    evaluated: dict[str, str] = {}   # resolved evaluation config (result-relevant keys) -> row that ran it
    with ResultsDir(out, files=(MANIFEST_NAME, "study.yaml")) as root:   # a lock: two studies cannot interleave
        root.write_text("study.yaml", study_path.read_text(encoding="utf-8"))
        manifest = Manifest(root, study, study_path, extra)
        manifest.carry(_read_json(out / MANIFEST_NAME))
        manifest.write()   # the plan, before any row runs: a study cut short says what is pending
        for row in study.rows:
            if row.left_out:   # the manifest says so (Manifest): nothing runs
                continue
            if wanted is not None and row.name not in wanted:
                _register_finished(study, row, extra, manifest, evaluated)
                continue
            if not row.threshold_from:
                tune_dir = out / "tune" / row.name
                grid_rows, best = run_tune(study.config, study.tune_overrides(row, extra), study.tune.episodes,
                                           ",".join(repr(v) for v in study.grid(row)),
                                           ",".join(map(str, study.tune.min_areas)), study.tune.metric, tune_dir,
                                           force=force, progress=progress, extend=study.tune.extend)
                tuned[row.name] = {"dir": str(tune_dir.relative_to(out)), "command": _tune_command(study, row, extra, tune_dir),
                                   "metric": study.tune.metric, "threshold": best["threshold"],
                                   "min_area": best["min_area"], "grid": grid_rows, "commits": _tune_commits(tune_dir)}
                if manifest.data["rows"][row.name].get("status") != "done":   # tuned, not evaluated yet
                    manifest.update(row.name, status="tuned", tune=tuned[row.name], threshold=best["threshold"],
                                    min_area=best["min_area"])
            if only and row.name not in only:
                _register_finished(study, row, extra, manifest, evaluated)
                continue
            source = tuned[row.threshold_from or row.name]
            t, a = source["threshold"], source["min_area"]
            entry: dict = {"tune": tuned.get(row.name), "threshold": t, "min_area": a}
            try:
                cfg = load_config(study.config, study.eval_overrides(row, t, a, extra))
            except ConfigError as exc:
                print(f"study: row {row.name} skipped at goal_threshold={t:g}: {exc}")
                manifest.update(row.name, status="skipped", reason=str(exc), **entry)
                continue
            key = _eval_key(cfg)
            eval_dir = out / "eval" / row.name
            if key in evaluated:   # the same config as an earlier row: its records are this row's
                same = manifest.data["rows"][evaluated[key]]
                shared = {k: v for k, v in same.items() if k not in ("tune", "threshold_from", "overrides", "thresholds")}
                manifest.update(row.name, **{**shared, **entry, "same_as": evaluated[key]})
                continue
            indices = episode_indices(study.evaluate.episodes, cfg.env, cfg.run, progress)
            if progress:
                print(f"study: {row.name}: goal_threshold={t:g} goal_min_area_cells={a} -> {eval_dir}")
            summary = run_jobs([EpisodeJob(cfg, list(indices), eval_dir)], force=force, progress=progress)[0]
            n, seconds, commits = _episode_seconds(eval_dir / "episodes.jsonl", indices)
            evaluated[key] = row.name
            manifest.update(row.name, status="done", dir=str(eval_dir.relative_to(out)),
                            command=_eval_command(study, eval_dir), config=to_dict(cfg), commits=commits,
                            inputs=_read_json(eval_dir / INPUTS_NAME) or {},
                            episode_files=episode_files(cfg.env, indices.stop), episodes=n,
                            episode_seconds=round(seconds, 3),
                            summary={k: v for k, v in summary.items() if k != "per_category"}, **entry)
    return manifest.data


def _eval_key(cfg) -> str:
    """What makes two rows' evaluations the same: their resolved configs but the result-neutral keys."""
    return repr(strip_neutral(to_dict(cfg)))


def _register_finished(study: StudyConfig, row: StudyRow, extra: list[str], manifest: Manifest,
                       evaluated: dict[str, str]) -> None:
    """A row ``--rows`` leaves out but an earlier invocation finished still counts as an earlier
    row: a later row of the same evaluation config names its records (``same_as``) instead of
    running them again, as in a study run whole."""
    entry = manifest.data["rows"][row.name]
    if entry.get("status") != "done" or entry.get("same_as") or entry.get("threshold") is None:
        return
    manifest_row_records(manifest.root.path / MANIFEST_NAME, manifest.data, row.name)   # what it carries holds
    try:
        cfg = load_config(study.config, study.eval_overrides(row, entry["threshold"], entry["min_area"], extra))
    except ConfigError:
        return
    evaluated.setdefault(_eval_key(cfg), row.name)


def study_configs(args) -> list:
    """Every config ``calnav study`` runs (checked by the preflight before any row runs)."""
    return load_study(args.study, list(args.overrides))[1]


def main_study(args, configs) -> None:
    """``configs``: ``study_configs(args)``, checked by the preflight."""
    out = Path(args.output)
    only = tuple(s.strip() for s in (args.rows or "").split(",") if s.strip())
    manifest = run_study(args.study, out, list(args.overrides), force=args.force, only=only)
    rows = manifest["rows"]
    width = max(len(n) for n in rows)
    print(f"{'row'.ljust(width)}  status    threshold  Success        SPL            N")
    for name, e in rows.items():
        s = e.get("summary") or {}
        figures = (f"{e['threshold']:<9g}  {s['success']:.3f} ({s['success_sem']:.3f})  "
                   f"{s['spl']:.3f} ({s['spl_sem']:.3f})  {s['count']}") if s else e.get("reason", "")
        print(f"{name.ljust(width)}  {e['status']:<8}  {figures}")
    print(f"manifest: {out / MANIFEST_NAME}")
