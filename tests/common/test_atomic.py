"""common.atomic: whole-file and path-based atomic writes, and the rule that no other module
hand-writes one (every rename into place goes through common.atomic)."""
from __future__ import annotations

import ast
import re
import json
from pathlib import Path

import numpy as np
import pytest

from calnav.common.atomic import atomic_path, is_temp_file, temp_path, write_json_atomic, write_text_atomic

REPO_ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("common", "envs", "mapping", "agent", "eval")


def test_write_text_and_json_replace_and_leave_no_temp(tmp_path):
    p = tmp_path / "sub" / "a.txt"
    write_text_atomic(p, "old")
    write_text_atomic(p, "new")
    assert p.read_text() == "new"
    write_json_atomic(tmp_path / "b.json", {"x": 1})
    assert json.loads((tmp_path / "b.json").read_text()) == {"x": 1}
    assert sorted(f.name for f in tmp_path.rglob("*") if f.is_file()) == ["a.txt", "b.json"]


def test_atomic_path_keeps_suffix_for_savez_and_cleans_up_on_error(tmp_path):
    target = tmp_path / "arr.npz"
    with atomic_path(target) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".npz" and is_temp_file(tmp)
        np.savez_compressed(tmp, a=np.arange(3))  # no second ".npz" appended
    with np.load(target) as d:
        np.testing.assert_array_equal(d["a"], [0, 1, 2])
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half a file")
            raise RuntimeError("writer crashed")
    with np.load(target) as d:  # the old contents are intact, the temporary file is gone
        np.testing.assert_array_equal(d["a"], [0, 1, 2])
    assert [f.name for f in tmp_path.iterdir()] == ["arr.npz"]


def test_temp_names_unique_and_recognised():
    a, b = temp_path("/x/scene.npz"), temp_path("/x/scene.npz")
    assert a != b and is_temp_file(a) and is_temp_file(b)
    assert not is_temp_file("/x/scene.npz") and not is_temp_file("/x/house.tmp.json")


def _renames(tree: ast.AST) -> list[int]:
    """Line numbers of ``os.replace(...)`` / ``os.rename(...)`` / ``<path>.replace(<one arg>)``
    / ``<path>.rename(...)`` calls (str.replace takes two arguments, so it is not counted)."""
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            name, owner = node.func.attr, node.func.value
            if isinstance(owner, ast.Name) and owner.id == "os" and name in ("replace", "rename"):
                lines.append(node.lineno)
            elif name == "rename" or (name == "replace" and len(node.args) == 1 and not node.keywords):
                lines.append(node.lineno)
    return lines


def test_no_hand_written_atomic_writes_outside_common_atomic():
    found = []
    for pkg in PACKAGES:
        for path in sorted((REPO_ROOT / pkg).rglob("*.py")):
            if path == REPO_ROOT / "common" / "atomic.py":
                continue
            for line in _renames(ast.parse(path.read_text(), str(path))):
                found.append(f"{path.relative_to(REPO_ROOT)}:{line}")
    assert (REPO_ROOT / "common" / "atomic.py").exists()
    assert found == [], "rename into place by hand (use common.atomic): " + ", ".join(found)


def test_json_is_strict_and_names_the_non_finite_value(tmp_path):
    """json.dumps writes bare NaN / Infinity (not JSON) by default; calnav's one JSON writer
    refuses them, naming the file and the place, and leaves the file as it was."""
    import json
    import math

    from calnav.common.atomic import json_text, write_json_atomic

    assert json_text({"a": [1.5, None]}, indent=None) == '{"a": [1.5, null]}'
    path = write_json_atomic(tmp_path / "r.json", {"ok": 1})
    for bad, place in (({"m": {"ece": math.nan}}, "m.ece is nan"), ({"v": [0.0, -math.inf]}, "v[1] is -inf")):
        with pytest.raises(ValueError, match=rf"^{path}: {re.escape(place)}, which JSON cannot hold"):
            write_json_atomic(path, bad)
    assert json.loads(path.read_text()) == {"ok": 1}


def test_undefined_figures_are_written_as_null_and_infinities_still_refused(tmp_path):
    from calnav.common.atomic import undefined_as_null, write_json_atomic

    path = write_json_atomic(tmp_path / "m.json", undefined_as_null({"iou": [0.5, float("nan")], "auc": float("nan")}))
    assert json.loads(path.read_text()) == {"iou": [0.5, None], "auc": None}
    with pytest.raises(ValueError, match="inf"):
        write_json_atomic(tmp_path / "bad.json", undefined_as_null({"x": float("inf")}))
