"""common.provenance: the commit read from .git files equals git's own answer."""
from __future__ import annotations

import shutil
import subprocess

import pytest

from calnav.common.provenance import REPO_ROOT, git_commit


@pytest.mark.skipif(shutil.which("git") is None or not (REPO_ROOT / ".git").exists(),
                    reason="needs git and a checkout (an installed wheel has no commit)")
def test_commit_matches_git_rev_parse() -> None:
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO_ROOT, capture_output=True, text=True, check=True)
    assert git_commit() == head.stdout.strip()


def test_packed_and_detached_refs_and_no_checkout(tmp_path) -> None:
    sha = "0123456789abcdef0123456789abcdef01234567"
    assert git_commit(tmp_path) is None                       # no .git: an installed wheel
    git = tmp_path / ".git"
    git.mkdir()
    (git / "HEAD").write_text("ref: refs/heads/main\n")
    assert git_commit(tmp_path) is None                       # a ref that resolves nowhere
    (git / "packed-refs").write_text(f"# pack-refs with: peeled\n{sha} refs/heads/main\n")
    assert git_commit(tmp_path) == sha
    (git / "refs" / "heads").mkdir(parents=True)
    (git / "refs" / "heads" / "main").write_text(sha[::-1] + "\n")   # a loose ref wins over packed-refs
    assert git_commit(tmp_path) == sha[::-1]
    (git / "HEAD").write_text(sha + "\n")                     # detached
    assert git_commit(tmp_path) == sha


def test_environment_names_the_machine_and_differences_name_what_changed():
    from importlib import metadata

    from calnav.common.provenance import environment, environment_differences

    here = environment()
    assert here["packages"]["numpy"] == metadata.version("numpy") and here["cpus"] >= 1 and here["cpu"]
    there = {**here, "cpu": "Other CPU", "packages": {**here["packages"], "numpy": "0.1", "gone": "1.0"}}
    del there["packages"]["scipy"]
    assert environment_differences(there, here) == [
        f"cpu Other CPU there, {here['cpu']} here", "gone 1.0 there, (none) here",
        f"numpy 0.1 there, {here['packages']['numpy']} here", f"scipy (none) there, {here['packages']['scipy']} here"]
    assert environment_differences(here, here) == []
