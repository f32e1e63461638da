"""Per-episode records files (``episodes.jsonl``) and the one-line errors of results directories.

``RecordsFile`` is a run's records file: one JSON object per line, keyed by ``index``, appended
and flushed per record. ``read_records`` is the one reader of records files (every command that
reads ``episodes.jsonl`` goes through it: resume, ``report``, ``study``, ``compare``,
``reproduce``): it skips (with a warning naming the file and line) lines that are not JSON
objects with an integer ``index`` (a torn last line of a killed run, a stray ``5``); two records
of one index are one episode's result twice -- an exact duplicate (the same record, but for
where and when it ran: ``RECORD_PROVENANCE``) counts once, with a warning and a ``duplicates``
count, and two *different* records of one index are a ``ResultsError`` naming the episode and
the directory, since no reader can tell which one is the result. ``RecordsFile.resume`` also
drops the records to retry (crashed episodes) and rewrites the file atomically whenever it
dropped anything, so the file never holds two records of one index.

Every problem writing a results directory or its records (a read-only file system, a directory
in the way, a full disk) is a ``ResultsError`` with a one-line message (``calnav`` exits 2);
``eval.results_dir`` owns the directories themselves.
"""
from __future__ import annotations

import json
import os
import sys
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Iterator

from calnav.common.atomic import json_text, write_text_atomic
from calnav.eval.stats import METRICS, finite_or_error

RECORDS_NAME = "episodes.jsonl"
RECORD_KEY = "index"  # the field that identifies an episode's record
# Record fields saying where, when and by which code an episode ran, not what happened in it: two
# records of one index that differ only here are duplicates, not a conflict; ``calnav reproduce``
# compares every other field.
RECORD_PROVENANCE: tuple[str, ...] = ("wall_time_s", "commit", "ray_node", "video", "rerun")
MAX_NAMED_FIELDS = 3   # the differing fields a conflict names (the rest counted): one readable line


class ResultsError(Exception):
    """A results directory cannot be used, or a run produced no usable result (one line)."""


class AllEpisodesFailed(ResultsError):
    """Every episode of a run crashed: its numbers would be a table of zeros."""


def warn(message: str) -> None:
    """One warning line on stderr (kept out of stdout, which holds the results table)."""
    print(f"calnav: warning: {message}", file=sys.stderr)


@contextmanager
def writing(what: Path | str) -> Iterator[None]:
    """Turn an OSError (read-only file system, no permission, a directory in the way) while
    writing ``what`` into a one-line ResultsError naming it."""
    try:
        yield
    except OSError as exc:
        raise ResultsError(f"cannot write {what}: {exc.strerror or exc}") from exc


# ----------------------------------------------------------------------------- records
@dataclass
class RecordsRead:
    """What ``read_records`` found: one record per index (in file order of their first
    appearance; of exact duplicates the last), the number of duplicate records dropped, the
    damaged line numbers."""

    records: dict[int, dict] = field(default_factory=dict)
    duplicates: int = 0
    damaged: list[int] = field(default_factory=list)
    clean_end: bool = True  # the file ends with a newline (appends start on a fresh line)


def _parse(line: str) -> tuple[dict | None, str]:
    try:
        rec = json.loads(line)
    except json.JSONDecodeError as exc:
        return None, f"not JSON: {exc.msg}"
    if not isinstance(rec, dict):
        return None, f"a JSON {type(rec).__name__}, not an object"
    if not isinstance(rec.get(RECORD_KEY), int) or isinstance(rec.get(RECORD_KEY), bool):
        return None, f"no integer {RECORD_KEY!r}"
    if rec.get("status", "ok") == "ok":   # a finished episode carries every metric (a crash record: its error)
        missing = [m for m in METRICS if not isinstance(rec.get(m), (int, float)) or isinstance(rec.get(m), bool)]
        if missing:
            return None, f"episode {rec[RECORD_KEY]} has no number for {', '.join(missing)}; it runs again"
    # a NaN / infinite metric (a file written before records were checked): an error record,
    # counted as failed and retried on resume like a crash (eval.stats.finite_or_error)
    return finite_or_error(rec), ""


def _result(record: dict) -> dict:
    """What a record says the episode did: the record without ``RECORD_PROVENANCE``."""
    return {k: v for k, v in record.items() if k not in RECORD_PROVENANCE}


def _same_result(a: dict, b: dict) -> bool:
    """Whether two records of one index say the same (compared as JSON text: NaN equals NaN)."""
    return json.dumps(_result(a), sort_keys=True) == json.dumps(_result(b), sort_keys=True)


def _conflict(path: Path, index: int, lines: tuple[int, int], a: dict, b: dict) -> ResultsError:
    """The one-line error of two different records of episode ``index`` in ``path``."""
    ra, rb = _result(a), _result(b)
    keys = sorted(k for k in ra.keys() | rb.keys() if ra.get(k, "(absent)") != rb.get(k, "(absent)"))
    named = ", ".join(f"{k} {ra.get(k, '(absent)')} vs {rb.get(k, '(absent)')}" for k in keys[:MAX_NAMED_FIELDS])
    more = f" and {len(keys) - MAX_NAMED_FIELDS} more field(s)" if len(keys) > MAX_NAMED_FIELDS else ""
    return ResultsError(f"{path.parent}: episode {index} has two different records ({path.name} lines {lines[0]} and "
                        f"{lines[1]}: {named}{more}); one episode has one result: delete the wrong line (or both, "
                        "and rerun the same command to run the episode again)")


def read_records(path: str | os.PathLike, quiet: bool = False) -> RecordsRead:
    """The records of ``path`` (missing file: none). Damaged lines are skipped and exact
    duplicates dropped, each with a warning unless ``quiet``; two different records of one
    index are a ResultsError (module docstring)."""
    path = Path(path)
    out = RecordsRead()
    if not path.exists():
        return out
    if path.is_dir():
        raise ResultsError(f"{path} is a directory, not a records file")
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise ResultsError(f"cannot read {path}: {exc.strerror or exc}") from None
    out.clean_end = not text or text.endswith("\n")
    dup_indices, first_line = [], {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        rec, why = _parse(line)
        if rec is None:
            out.damaged.append(lineno)
            if not quiet:
                warn(f"{path}:{lineno}: skipped a damaged record ({why})")
            continue
        i = rec[RECORD_KEY]
        if i in out.records:
            if not _same_result(out.records[i], rec):
                raise _conflict(path, i, (first_line[i], lineno), out.records[i], rec)
            out.duplicates += 1
            dup_indices.append(i)
        first_line.setdefault(i, lineno)
        out.records[i] = rec
    if out.duplicates and not quiet:
        shown = ", ".join(str(i) for i in sorted(set(dup_indices)))
        warn(f"{path}: {out.duplicates} duplicate record(s) of episode(s) {shown}; each episode counts once "
             "(the records are the same result)")
    return out


class RecordsFile:
    """The append-only records file of one run (see the module docstring)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._f = None

    def resume(self, retry: Callable[[dict], bool] = lambda r: False,
               indices: Iterable[int] | None = None) -> RecordsRead:
        """Read the records, drop those of ``indices`` (default: all) for which ``retry`` is true,
        and rewrite the file atomically if anything was dropped (damaged lines, duplicates,
        retried records, a torn end). Returns what was kept."""
        read = read_records(self.path)
        scope = None if indices is None else set(indices)
        kept = {i: r for i, r in read.records.items() if not ((scope is None or i in scope) and retry(r))}
        if len(kept) < len(read.records) or read.damaged or read.duplicates or not read.clean_end:
            with writing(self.path):
                write_text_atomic(self.path, "".join(json_text(r, None, what=str(self.path)) + "\n"
                                                     for r in kept.values()))
        read.records = kept
        return read

    def __enter__(self) -> "RecordsFile":
        with writing(self.path):
            # unbuffered: each record goes to the file in ``append`` itself, so a failed append
            # (disk full) leaves nothing in a buffer for ``close`` to fail on a second time
            self._f = open(self.path, "ab", buffering=0)
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if self._f is None:
            return
        f, self._f = self._f, None
        try:
            f.close()
        except OSError as err:
            if exc_type is None:
                raise ResultsError(f"cannot write {self.path}: {err.strerror or err}") from err
            # else the error already on its way out is the one to report: not masked by this one

    def append(self, record: dict) -> None:
        """Append one record (one JSON line), written through to the file before it returns, so
        a killed run loses only the episodes in flight. A write that fails part-way (disk full)
        is cut off again, so the file keeps ending with whole records; ResultsError (one line)."""
        data = memoryview((json_text(record, None, str(self.path)) + "\n").encode())   # strict: no NaN
        with writing(self.path):
            end = os.fstat(self._f.fileno()).st_size
            try:
                while data:   # an unbuffered write may write only part (a nearly full disk)
                    data = data[self._f.write(data):]
            except OSError:
                try:
                    os.ftruncate(self._f.fileno(), end)
                except OSError:
                    pass   # a torn last line is skipped, with a warning, when the run is resumed
                raise
