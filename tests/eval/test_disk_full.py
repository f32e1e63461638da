"""A disk that fills while ``episodes.jsonl`` is appended: one ResultsError line (exit 2), not an
OSError from the records file's close masking it, and the records written before stay whole.

The disk is simulated under the file object (``eval.records``'s ``open``): its raw writes stop at
a byte quota, the last one part-way, then fail with ENOSPC, as a full file system's do; the
buffered and text layers above are Python's own, whatever mode the file is opened in. Where a
user namespace is allowed (``unshare -rm``, no root), a real tiny tmpfs fills up as well."""
from __future__ import annotations

import errno
import io
import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from calnav.eval import records
from calnav.eval.cli import main
from calnav.eval.records import RECORDS_NAME as RECORDS
from calnav.eval.records import RecordsFile, ResultsError
from tests.conftest import read_records

UNLIMITED = 1 << 62   # bytes
RECORD = {"index": 0, "status": "error", "error": "x" * 100}


class FullDisk(io.FileIO):
    """A file on a disk with ``quota`` bytes left: writes past it are cut, then fail (ENOSPC)."""

    quota = 0

    def write(self, data) -> int:
        data = memoryview(data).cast("B")
        left = FullDisk.quota - self.seek(0, io.SEEK_END)
        if left <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        return super().write(data[:left])


def full_disk_open(file, mode="r", buffering=-1, encoding=None, errors=None, newline=None, **_):
    """``open`` on the simulated disk (the layers above the raw file as ``io.open`` builds them)."""
    raw = FullDisk(file, mode.replace("b", "").replace("t", ""))
    if buffering == 0:
        return raw
    buffered = io.BufferedWriter(raw)
    return buffered if "b" in mode else io.TextIOWrapper(buffered, encoding=encoding, errors=errors,
                                                         newline=newline, write_through=False)


@pytest.fixture
def full_disk(monkeypatch):
    monkeypatch.setattr(records, "open", full_disk_open, raising=False)
    monkeypatch.setattr(FullDisk, "quota", UNLIMITED)   # until a test sets it
    return FullDisk


def test_a_full_disk_is_one_results_error_and_keeps_the_records(tmp_path, full_disk):
    line = json.dumps(RECORD) + "\n"
    full_disk.quota = len(line) + len(line) // 2   # room for one record and half of the next
    path = tmp_path / "episodes.jsonl"
    with pytest.raises(ResultsError) as exc:
        with RecordsFile(path) as records:
            records.append(RECORD)
            records.append({**RECORD, "index": 1})
    assert str(exc.value) == f"cannot write {path}: No space left on device"
    assert path.read_text() == line   # the half-written record is cut off again


SMALL = ["env.resolution=32x24", "env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=3",
         "env.max_episode_steps=20", "run.workers=1", "run.agent=oracle"]


def test_objectnav_on_a_full_disk_exits_2_with_one_line(tmp_path, full_disk, capsys):
    out = tmp_path / "run"
    assert main(["objectnav", "--episodes", "0:3", "--output", str(out), *SMALL]) == 0
    first = (out / "episodes.jsonl").read_text().splitlines(keepends=True)
    (out / "episodes.jsonl").write_text(first[0])   # one finished episode; the others are to run
    capsys.readouterr()
    # the next record fits (whichever runs next), the third does not
    full_disk.quota = len(first[0]) + max(map(len, first[1:])) + 10
    assert main(["objectnav", "--episodes", "0:3", "--output", str(out), *SMALL]) == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1] == (f"calnav objectnav: error: cannot write {out / 'episodes.jsonl'}: "
                                            "No space left on device")
    assert "Traceback" not in err
    kept = read_records(out)
    assert len(kept) == 2 and all(r["status"] == "ok" for r in kept.values())


PAGE = 4096   # bytes: tmpfs counts a file's size in whole pages
TINY = ["--agent", "oracle", "env.resolution=32x24", "env.dataset.val_scenes=2", "env.dataset.episodes_per_scene=6",
        "run.workers=1"]


def _unshare_works() -> bool:
    """Whether this user can mount a tmpfs in a user namespace of its own (no root needed)."""
    if shutil.which("unshare") is None:
        return False
    return subprocess.run(["unshare", "-rm", "true"], capture_output=True).returncode == 0


@pytest.mark.skipif(not _unshare_works(), reason="needs unshare -rm (a user namespace) to mount a tiny tmpfs")
def test_objectnav_on_a_really_full_tmpfs(tmp_path):
    """A real ENOSPC: the results directory on a tmpfs with one page left for episodes.jsonl
    (sized from the same run's other files on a normal disk): exit 2, one line, whole records."""
    sized = tmp_path / "sized"
    assert main(["objectnav", "--episodes", "0:1", "--output", str(sized), *TINY]) == 0
    before_records = (".lock", "config.yaml", "inputs.json", "environment.jsonl")   # written at open
    pages = sum(math.ceil(max(1, (sized / n).stat().st_size) / PAGE) for n in before_records)
    disk, err, kept = tmp_path / "tiny", tmp_path / "err.txt", tmp_path / "kept.jsonl"
    disk.mkdir()
    out = disk / "run"
    # the mount lives as long as the namespace: the records are copied out before it ends
    script = (f'mount -t tmpfs -o size={(pages + 1) * PAGE} tmpfs "{disk}" || exit 99; '
              f'"{sys.executable}" -m calnav objectnav --episodes 0:12 --output "{out}" {" ".join(TINY)} '
              f'> "{err}" 2>&1; rc=$?; cp "{out / RECORDS}" "{kept}"; exit $rc')
    repo = str(Path(__file__).resolve().parents[2])
    res = subprocess.run(["unshare", "-rm", "sh", "-c", script], env={**os.environ, "PYTHONPATH": repo})
    lines = err.read_text().replace("\r", "\n").strip().splitlines()
    assert res.returncode == 2 and "Traceback" not in "\n".join(lines), lines
    assert lines[-1] == f"calnav objectnav: error: cannot write {out / RECORDS}: No space left on device"
    records = [json.loads(line) for line in kept.read_text().splitlines()]   # every line whole
    assert 1 <= len(records) < 12 and all(r["status"] == "ok" for r in records)
