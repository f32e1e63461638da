"""The one owner of calnav results directories (``objectnav``, ``tune``, ``calibrate-map``,
``fit-glfs`` all go through it).

``ResultsDir(path, cfg, force=...)``, used as a context manager, opens a results directory:

1. ``path`` must be a directory (created if missing) that this process can write;
2. a lock: ``fcntl.flock`` on ``<path>/.lock``, held open for the run's lifetime. A second run
   into the same directory is refused (``ResultsError``, one line) while the first holds it; the
   kernel drops the lock when its holder exits or is killed (kill -9 included), so it never
   stays stuck;
3. the config check, one meaning everywhere: the saved ``config.yaml`` and ``cfg`` are compared
   as resolved config dicts without the result-neutral keys (``NEUTRAL_KEYS``), the saved one
   read with moved keys at their new place (``eval.config.MOVED_KEYS``: a directory written
   before a key moved is the same config), and so are the files the config reads
   (``eval.inputs``: weights, GLFS parameters, ..., by sha256, saved in ``inputs.json``, whose
   labels are migrated the same way; a retrained ``agent/weights/<model>.pt`` under an unchanged
   config is another run), and, where the command says how (``other_records``), the records
   themselves (an episode run's records name their episodes: scans made elsewhere place other
   episodes under the same indices); a difference is refused unless ``force``, which deletes the
   directory's results (``discard``). A directory from before ``inputs.json`` existed is resumed
   with a warning;
4. ``config.yaml`` and ``inputs.json`` are (re)written atomically, and a line is appended to
   ``environment.jsonl``: the date, the commit and ``common.provenance.environment()`` (CPU,
   Python, package versions) of this open. A refusal of other records names how the last
   line's environment differs from this one's: scans, and the episodes on them, can differ
   between machines or library versions with the code unchanged.

``eval.records`` owns the per-episode records file (``episodes.jsonl``, ``RecordsFile``,
``read_records``) and the errors and warnings of both.

Every problem with the directory (a file where a directory or a file is expected, a read-only
file system, a held lock) is a ``ResultsError`` with a one-line message (``calnav`` exits 2).
"""
from __future__ import annotations

import fcntl
import json
import os
import shutil
from pathlib import Path
from typing import Callable, Iterable

import yaml

from calnav.common.atomic import json_text, write_text_atomic
from calnav.eval.inputs import INPUTS_NAME, changed_inputs, input_fingerprints, read_saved_inputs
from calnav.eval.records import (RECORD_KEY, RECORD_PROVENANCE, RECORDS_NAME, AllEpisodesFailed,  # noqa: F401
                                 RecordsFile, RecordsRead, ResultsError, read_records, warn, writing)   # (re-exported: the results API)

# Dotted config keys that do not change results: a rerun with other values may resume the same
# directory, and `calnav compare` never makes them columns.
NEUTRAL_KEYS: tuple[str, ...] = ("run.workers", "run.output_dir", "run.backend", "run.ray_address",
                                 "segmenter.trace")   # (trace: bit-identical logits)
# How many houses a split has decides which episodes exist, never what an index holds (indices
# run over the split's houses in order, ``eval.episodes``; a house's seed is its split and
# position): a directory of per-episode records resumes across these, so an evaluation can add
# houses without rerunning the episodes it has. Not neutral elsewhere (training reads them).
SPLIT_SIZE_KEYS: tuple[str, ...] = tuple(f"env.dataset.{split}_scenes" for split in ("train", "val", "test", "calib"))
EPISODE_NEUTRAL_KEYS: tuple[str, ...] = NEUTRAL_KEYS + SPLIT_SIZE_KEYS
LOCK_NAME = ".lock"
CONFIG_NAME = "config.yaml"
ENVIRONMENT_NAME = "environment.jsonl"   # one line per open that wrote: where the results were made


def _one_line(text: str) -> str:
    """``text`` with control characters (a newline in a value read from a file) as spaces: an
    error message stays one line."""
    return "".join(" " if ord(c) < 32 or ord(c) == 127 else c for c in text)


def check_output_dir(path: Path | str, option: str = "--output") -> Path:
    """An output *directory* a command without a results-directory owner writes into, checked
    before any work: not a file, and creatable (see ``check_output_file``)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ResultsError(f"{option} {path} is a file, not a directory; pass a directory")
    if not path.exists():
        check_output_file(path, option)   # the nearest existing parent must be a writable directory
    elif not os.access(path, os.W_OK | os.X_OK):
        raise ResultsError(f"{option} {path} is not writable")
    return path


def check_output_file(path: Path | str, option: str = "--output") -> Path:
    """An output *file* the command will write at its end, checked before any work: not a
    directory, and its nearest existing parent a writable directory (missing ones are created
    at write time). ResultsError in one line otherwise."""
    path = Path(path)
    if path.is_dir():
        raise ResultsError(f"{option} {path} is a directory; give a file name")
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise ResultsError(f"{option} {path}: {parent} is a file, not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ResultsError(f"{option} {path}: {parent} is not writable")
    return path


def flatten(tree: dict, prefix: str = "") -> dict[str, object]:
    """{'a': {'b': 1}} -> {'a.b': 1} (lists stay values)."""
    out: dict[str, object] = {}
    for k, v in tree.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


MAX_NAMED_DIFFERENCES = 3    # config keys a refusal names (the rest counted): one readable line


def config_differences(saved: dict, current: dict) -> str:
    """The dotted keys in which two resolved configs differ, each with both values ('mapping.fusion:
    averaging there, rbu here'), the first few named and the rest counted."""
    a, b = flatten(saved), flatten(current)
    keys = sorted(k for k in a.keys() | b.keys() if a.get(k, "(absent)") != b.get(k, "(absent)"))
    named = [f"{k}: {a.get(k, '(absent)')} there, {b.get(k, '(absent)')} here" for k in keys[:MAX_NAMED_DIFFERENCES]]
    more = f"; {len(keys) - MAX_NAMED_DIFFERENCES} more key(s)" if len(keys) > MAX_NAMED_DIFFERENCES else ""
    return "; ".join(named) + more


def strip_neutral(cfg_dict: dict, neutral_keys: Iterable[str] = NEUTRAL_KEYS) -> dict:
    """A deep copy of a resolved config dict without the dotted ``neutral_keys``."""
    out = json.loads(json.dumps(cfg_dict))
    for dotted in neutral_keys:
        *sections, key = dotted.split(".")
        node = out
        for s in sections:
            node = node.get(s, {}) if isinstance(node, dict) else {}
        if isinstance(node, dict):
            node.pop(key, None)
    return out


class ResultsDir:
    """An opened, locked results directory (see the module docstring). ``cfg``: the run's
    config dataclass, or None for a directory that only groups others (a tune or multirun
    root: locked, no config). ``discard``: names removed by ``force`` when the config differs.
    ``files``: names that must be files, not directories, when they exist. ``option``: the
    command-line option that names the directory, for messages."""

    def __init__(self, path: str | os.PathLike, cfg=None, *, force: bool = False,
                 discard: tuple[str, ...] = (RECORDS_NAME,), files: tuple[str, ...] = (RECORDS_NAME,),
                 neutral_keys: tuple[str, ...] = NEUTRAL_KEYS, option: str = "--output",
                 segmenters: tuple[str, ...] | None = None, can_force: bool = True,
                 other_records: Callable[[Path], str | None] | None = None):
        self.path = Path(path)
        self.other_records = other_records   # (records path) -> how its records are not this run's, or None
        self.cfg, self.force, self.discard, self.files = cfg, force, discard, files
        self.neutral_keys, self.option = neutral_keys, option
        self.segmenters = segmenters   # the segmenters this command runs, when not the config's (eval.inputs)
        self._remedy = f"use another {option}" + (", or --force to discard them" if can_force else "")
        self._lock_fd: int | None = None
        self._fingerprints: dict | None = None

    # ------------------------------------------------------------------ open / close
    def __enter__(self) -> "ResultsDir":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def open(self) -> "ResultsDir":
        if self.path.exists() and not self.path.is_dir():
            raise ResultsError(f"{self.option} {self.path} is a file, not a directory; pass a directory")
        with writing(f"results directory {self.path}"):
            self.path.mkdir(parents=True, exist_ok=True)
        self._lock()
        try:
            for name in (CONFIG_NAME, *self.files):
                if (self.path / name).is_dir():
                    raise ResultsError(f"{self.path / name} is a directory, not a file; remove it or "
                                       f"pass another {self.option}")
            if self.cfg is not None:
                self._check_config()
        except BaseException:
            self.close()
            raise
        return self

    def check(self, read_only: bool = False) -> "ResultsDir":
        """What ``open`` would refuse, found without writing anything (for a command that works
        in memory first and writes only at its end): a file in the way, an unwritable parent,
        a run holding the directory, another config's results without ``force``. ``read_only``:
        the directory is only read (its results compared), so it must exist, not be writable."""
        if read_only:
            if not self.path.is_dir():
                raise ResultsError(f"{self.option} {self.path} is not a directory; give a results directory")
        else:
            check_output_dir(self.path, self.option)   # a file in the way, an unwritable parent or directory
        if not self.path.exists():
            return self
        lock = self.path / LOCK_NAME
        if lock.exists():
            with writing(f"lock file {lock}"):
                fd = os.open(lock, os.O_RDONLY)
            try:
                self._flock_or_refuse(fd, fcntl.LOCK_SH)   # released with the descriptor below
            finally:
                os.close(fd)
        if self.cfg is not None and not self.force:
            refusal = self._refusal()
            if refusal is not None:
                raise ResultsError(refusal)
        return self

    def close(self) -> None:
        if self._lock_fd is not None:
            os.close(self._lock_fd)  # closing the last descriptor releases the flock
            self._lock_fd = None

    def _flock_or_refuse(self, fd: int, mode: int) -> None:
        """flock ``fd`` without waiting; ResultsError naming the holder's pid when another run has it."""
        try:
            fcntl.flock(fd, mode | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode(errors="replace").strip() or "unknown"
            raise ResultsError(f"{self.path} is in use by another calnav run (pid {holder}); wait for it "
                               f"to finish or pass another {self.option}") from None

    def _lock(self) -> None:
        lock = self.path / LOCK_NAME
        with writing(f"lock file {lock}"):
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            self._flock_or_refuse(fd, fcntl.LOCK_EX)
        except ResultsError:
            os.close(fd)
            raise
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._lock_fd = fd

    def _cfg_dict(self) -> dict:
        from calnav.eval.config import dump_yaml

        return yaml.safe_load(dump_yaml(self.cfg))

    def _inputs(self) -> dict:
        """The fingerprints of the files ``cfg`` reads (``eval.inputs``), computed once per open."""
        if self._fingerprints is None:
            try:
                self._fingerprints = input_fingerprints(self._cfg_dict(), self.neutral_keys, self.segmenters)
            except OSError as exc:   # an input file that exists but cannot be read
                raise ResultsError(f"cannot read an input file of the config: {exc}") from None
        return self._fingerprints

    def _other_config(self) -> str | None:
        """How the directory's config.yaml (if any) differs from ``cfg`` beyond the neutral keys
        (``config_differences``), the saved one read with moved keys at their new place; None
        when it does not."""
        from calnav.eval.config import ConfigError, migrate_tree

        saved = self.path / CONFIG_NAME
        if not saved.exists():
            return None
        try:
            old = yaml.safe_load(saved.read_text()) or {}
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            raise ResultsError(f"{saved} is not a readable config ({type(exc).__name__}); remove it or "
                               f"pass another {self.option}") from None
        if not isinstance(old, dict):
            return "not a config mapping"
        try:
            old = migrate_tree(old)
        except ConfigError:   # a key at its old and its new place: not a config calnav wrote
            return "a key at both its old and its new place: not a config calnav wrote"
        old, new = strip_neutral(old, self.neutral_keys), strip_neutral(self._cfg_dict(), self.neutral_keys)
        return config_differences(old, new) if old != new else None

    def _other_inputs(self) -> list[str]:
        """The labels of the input files that differ from the ones the directory's results were
        made with ([] when the same, or when the directory predates ``inputs.json``: warned)."""
        if not (self.path / CONFIG_NAME).exists():
            return []
        try:
            saved = read_saved_inputs(self.path / INPUTS_NAME)
        except ValueError as exc:
            raise ResultsError(f"{exc}; remove it or pass another {self.option}") from None
        if saved is None:
            warn(f"{self.path} has no {INPUTS_NAME} (made before calnav fingerprinted its input files): calnav "
                 "cannot check that its weights and parameter files are the ones its results were made with")
            return []
        from calnav.eval.config import migrate_key

        return changed_inputs({migrate_key(k): v for k, v in saved.items()}, self._inputs())

    def _refusal(self) -> str | None:
        """Why the directory's results are not this run's (one line), or None."""
        differences = self._other_config()
        if differences is not None:
            return (f"{self.path} holds results of a different config ({self.path / CONFIG_NAME}: {differences}); "
                    f"{self._remedy}")
        changed = self._other_inputs()
        if changed:
            files = ", ".join(f"{k} ({self._inputs()[k]['path']})" for k in changed)
            return (f"{self.path} holds results made with other input files: {files} changed since "
                    f"({self.path / INPUTS_NAME}); {self._remedy}")
        other = self.other_records(self.path / RECORDS_NAME) if self.other_records else None
        if other is not None:
            return f"{self.path} holds other records: {other}{self._environment_note()}; {self._remedy}"
        return None

    def recorded_environment(self) -> dict | None:
        """The environment of the last open that wrote the directory (``ENVIRONMENT_NAME``'s
        last readable line), None when it has none (a directory from before it existed)."""
        path = self.path / ENVIRONMENT_NAME
        if not path.is_file():
            return None
        try:
            text = path.read_text(encoding="utf-8", errors="replace")
        except OSError:
            return None   # unreadable: the refusal is made without the note
        last = None
        for line in text.splitlines():
            try:
                entry = json.loads(line)
            except json.JSONDecodeError:
                continue   # a torn line: the one before it says as much
            last = entry if isinstance(entry, dict) else last
        return last

    def _environment_note(self) -> str:
        """' (recorded ...: what differs)' between the directory's last environment and this
        process's; '' when the directory recorded none."""
        from calnav.common.provenance import environment, environment_differences

        recorded = self.recorded_environment()
        if recorded is None:
            return ""
        differs = [_one_line(d) for d in environment_differences(recorded, environment())]
        when = f"recorded {_one_line(str(recorded.get('date', '?')))} ({ENVIRONMENT_NAME})"
        if not differs:
            return f" ({when} with the CPU model and package versions of this machine)"
        more = f"; {len(differs) - MAX_NAMED_DIFFERENCES} more" if len(differs) > MAX_NAMED_DIFFERENCES else ""
        return f" ({when}: {'; '.join(differs[:MAX_NAMED_DIFFERENCES])}{more})"

    def _check_config(self) -> None:
        from calnav.eval.config import dump_yaml

        refusal = self._refusal()
        if refusal is not None:
            if not self.force:
                raise ResultsError(refusal)
            self._discard()
        self.write_text(CONFIG_NAME, dump_yaml(self.cfg))
        self.write_json(INPUTS_NAME, self._inputs())
        self._append_environment()

    def _append_environment(self) -> None:
        from datetime import datetime, timezone

        from calnav.common.provenance import environment, running_commit

        entry = {"date": datetime.now(timezone.utc).isoformat(timespec="seconds"), "commit": running_commit(),
                 **environment()}
        path = self.path / ENVIRONMENT_NAME
        with writing(path):
            with open(path, "a+b") as f:   # after a torn last line, on a line of its own
                torn = f.tell() > 0 and (f.seek(-1, os.SEEK_END), f.read(1))[1] != b"\n"
                f.write((("\n" if torn else "") + json_text(entry, None, what=str(path)) + "\n").encode())

    def _discard(self) -> None:
        with writing(f"results in {self.path}"):
            for name in (*self.discard, ENVIRONMENT_NAME):   # the environments of the results discarded
                p = self.path / name
                if p.is_dir():
                    shutil.rmtree(p)
                else:
                    p.unlink(missing_ok=True)

    # ------------------------------------------------------------------------ writes
    def write_text(self, name: str, text: str) -> Path:
        """Write ``<dir>/name`` atomically."""
        with writing(self.path / name):
            return write_text_atomic(self.path / name, text)

    def write_json(self, name: str, obj) -> Path:
        """Write ``<dir>/name`` as strict JSON (``common.atomic.json_text``: a NaN or infinity is
        a ValueError naming the file and the key, never a bare ``NaN`` in the file)."""
        return self.write_text(name, json_text(obj, 2, what=str(self.path / name)) + "\n")

    def records(self, name: str = RECORDS_NAME) -> "RecordsFile":
        return RecordsFile(self.path / name)
