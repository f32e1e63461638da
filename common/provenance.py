"""Where a result came from: the source commit the running code was checked out at.

Read from the repository's ``.git`` files (``HEAD``, a loose ref or ``packed-refs``), not by
running git: a manifest is written by library code that starts no processes, and an installed
wheel (no ``.git``) answers ``None`` rather than failing.
"""
from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
_SHA = re.compile(r"^[0-9a-f]{40}$")


def _git_dir(root: Path) -> Path | None:
    """The git directory of the checkout at ``root``: ``.git`` itself, or the one a worktree's
    ``.git`` file points to (``gitdir: PATH``)."""
    dot = root / ".git"
    if dot.is_dir():
        return dot
    if dot.is_file():
        text = dot.read_text(encoding="utf-8").strip()
        if text.startswith("gitdir:"):
            path = Path(text.partition(":")[2].strip())
            return path if path.is_absolute() else (root / path).resolve()
    return None


def _common_dir(git_dir: Path) -> Path:
    """Where a worktree's shared refs live (its ``commondir``), else ``git_dir`` itself."""
    common = git_dir / "commondir"
    if common.is_file():
        path = Path(common.read_text(encoding="utf-8").strip())
        return path if path.is_absolute() else (git_dir / path).resolve()
    return git_dir


def git_commit(root: Path = REPO_ROOT) -> str | None:
    """The 40-hex commit ``HEAD`` names in the checkout at ``root``; None without one (an
    installed wheel) or when the ref cannot be resolved."""
    git_dir = _git_dir(root)
    if git_dir is None or not (git_dir / "HEAD").is_file():
        return None
    head = (git_dir / "HEAD").read_text(encoding="utf-8").strip()
    if _SHA.match(head):            # a detached HEAD
        return head
    if not head.startswith("ref:"):
        return None
    ref = head.partition(":")[2].strip()
    for base in (git_dir, _common_dir(git_dir)):
        loose = base / ref
        if loose.is_file():
            sha = loose.read_text(encoding="utf-8").strip()
            return sha if _SHA.match(sha) else None
    packed = _common_dir(git_dir) / "packed-refs"
    if packed.is_file():
        for line in packed.read_text(encoding="utf-8").splitlines():
            sha, _, name = line.partition(" ")
            if name.strip() == ref and _SHA.match(sha):
                return sha
    return None


@lru_cache(maxsize=1)
def running_commit() -> str | None:
    """The commit of the code this process runs (``git_commit`` read once, at the first call:
    a checkout moved later does not change the code already imported). Every episode record
    carries it, so a results directory resumed across commits says which commit made which
    record."""
    return git_commit()
