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


# The packages a result can depend on below calnav's own code: scans, navmeshes and episodes
# go through numpy / scipy / Open3D / scikit-image / trimesh / OpenCV, segmenters through torch.
ENVIRONMENT_PACKAGES: tuple[str, ...] = ("numpy", "scipy", "open3d", "torch", "scikit-image", "trimesh",
                                         "opencv-python-headless", "opencv-python")


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), else ``platform.processor()``, else '?'."""
    import platform

    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or "?"


@lru_cache(maxsize=1)
def environment() -> dict:
    """Where a result was made beyond the commit: the CPU model and count, the system, Python
    and the installed versions of ``ENVIRONMENT_PACKAGES`` (from their metadata, nothing
    imported; a package not installed is left out). Scanned houses, and the episodes placed
    on them, can differ between machines and library versions with the code unchanged, so a
    results directory keeps this beside its records (``eval.results_dir``)."""
    import os
    import platform
    from importlib import metadata

    packages = {}
    for name in ENVIRONMENT_PACKAGES:
        try:
            packages[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return {"cpu": cpu_model(), "cpus": os.cpu_count(), "system": platform.platform(),
            "python": platform.python_version(), "packages": packages}


def environment_differences(recorded: dict, here: dict) -> list[str]:
    """'what: recorded there, here' for the CPU model, Python and each package whose version
    differs between two ``environment()`` dicts (a package only one side has counts; a
    ``packages`` that is no mapping, as a damaged file may hold, counts as none)."""
    out = [f"{key} {recorded.get(key, '?')} there, {here.get(key, '?')} here"
           for key in ("cpu", "python") if recorded.get(key) != here.get(key)]
    a, b = (p if isinstance(p, dict) else {} for p in (recorded.get("packages"), here.get("packages")))
    out += [f"{name} {a.get(name, '(none)')} there, {b.get(name, '(none)')} here"
            for name in sorted(a.keys() | b.keys()) if a.get(name) != b.get(name)]
    return out
