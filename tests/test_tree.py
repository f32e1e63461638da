"""The tests mirror the source tree: every folder under tests/ is a package folder of calnav
(tests/eval/objectnav tests eval/objectnav), so a test is found where its code is."""
from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
TESTS = REPO_ROOT / "tests"


def test_every_test_folder_mirrors_a_source_folder() -> None:
    folders = [p for p in TESTS.rglob("*") if p.is_dir() and p.name != "__pycache__"]
    assert folders, "no test folders found: the scan looked in the wrong place"
    for folder in folders:
        source = REPO_ROOT / folder.relative_to(TESTS)
        assert source.is_dir() and (source / "__init__.py").is_file(), \
            f"{folder.relative_to(REPO_ROOT)} mirrors no source package ({source.relative_to(REPO_ROOT)})"
        assert (folder / "__init__.py").is_file(), f"{folder.relative_to(REPO_ROOT)} lacks __init__.py"


def test_eval_subpackages_with_tests_live_in_their_folder() -> None:
    """A test module named after an eval subpackage's command sits in that subpackage's folder."""
    flat = {p.name for p in (TESTS / "eval").glob("test_*.py")}
    subpackages = {p.name for p in (REPO_ROOT / "eval").iterdir() if (p / "__init__.py").is_file()}
    misplaced = sorted(name for name in flat for sub in subpackages if name.startswith(f"test_{sub}"))
    assert not misplaced, f"move {misplaced} into tests/eval/<subpackage>/"
