"""common.npz: versioned .npz round trip and clear errors (naming the file) for a missing file,
a file that is not a .npz, a missing format version and a wrong one."""
import json

import numpy as np
import pytest

from calnav.common.npz import NpzFormatError, check_format_version, load_versioned_npz, save_versioned_npz


def test_round_trip(tmp_path):
    arrays = {"a": np.arange(6, dtype=np.int16).reshape(2, 3), "b": np.array([0.5, np.inf], np.float32)}
    path = save_versioned_npz(tmp_path / "sub" / "x.npz", arrays, {"name": "x", "nested": {"k": [1, 2]}}, version=3)
    assert path == tmp_path / "sub" / "x.npz" and not list(path.parent.glob("*.tmp.npz"))
    loaded, meta = load_versioned_npz(path, 3)
    assert meta == {"format_version": 3, "name": "x", "nested": {"k": [1, 2]}}
    assert loaded.keys() == arrays.keys()
    for k in arrays:
        assert loaded[k].dtype == arrays[k].dtype and np.array_equal(loaded[k], arrays[k])


def test_wrong_version_names_the_file(tmp_path):
    path = save_versioned_npz(tmp_path / "old.npz", {"a": np.zeros(2)}, {}, version=1)
    with pytest.raises(NpzFormatError, match=r"widget file .*old\.npz has format 1, expected 2"):
        load_versioned_npz(path, 2, what="widget file")


def test_missing_version_names_the_file(tmp_path):
    path = tmp_path / "unversioned.npz"
    np.savez(path, a=np.zeros(2), meta=np.array(json.dumps({"name": "x"})))
    with pytest.raises(NpzFormatError, match=r"unversioned\.npz has no format_version"):
        load_versioned_npz(path, 1)
    with pytest.raises(NpzFormatError, match="no format_version"):
        check_format_version({}, 1, path)


@pytest.mark.parametrize("write", [
    lambda p: p.write_text("this is not a zip archive"),
    lambda p: p.write_bytes(b"PK\x03\x04 truncated zip"),
    lambda p: np.save(p.with_suffix(".npy"), np.zeros(3)) or p.with_suffix(".npy").rename(p),
    lambda p: np.savez(p, a=np.zeros(2)),                          # no meta record
    lambda p: np.savez(p, meta=np.array("{not json")),              # meta is not JSON
    lambda p: np.savez(p, meta=np.array(json.dumps([1, 2]))),       # meta is not an object
], ids=["text", "truncated_zip", "npy", "no_meta", "bad_json", "meta_not_object"])
def test_not_a_versioned_npz_names_the_file(tmp_path, write):
    path = tmp_path / "junk.npz"
    write(path)
    with pytest.raises(NpzFormatError, match=r"corrupt widget file .*junk\.npz"):
        load_versioned_npz(path, 1, what="widget file")


def test_missing_file_and_custom_error(tmp_path):
    class MyError(ValueError):
        pass

    with pytest.raises(MyError, match=r"widget file not found: .*nowhere\.npz"):
        load_versioned_npz(tmp_path / "nowhere.npz", 1, what="widget file", error=MyError)
    assert issubclass(NpzFormatError, ValueError)


def test_reserved_names_are_refused(tmp_path):
    with pytest.raises(ValueError, match="reserved"):
        save_versioned_npz(tmp_path / "x.npz", {"meta": np.zeros(1)}, {}, version=1)
    with pytest.raises(ValueError, match="format_version"):
        save_versioned_npz(tmp_path / "x.npz", {}, {"format_version": 1}, version=1)
