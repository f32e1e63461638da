"""Labelled PLY scans: label mapping, per-vertex/per-face labels, colours, up axis, floor shift,
instances, polygon faces and every error path."""
from __future__ import annotations

import json

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from calnav.envs.primitives import box_mesh
from calnav.envs.scan import load_labelled_ply
from calnav.envs.scene import SceneError
from calnav.envs.semantics import CLASS_ID, VOID

FLOOR_RAW, CHAIR_RAW, JUNK_RAW = 1, 5, 99        # raw label ids as a scanner would write them
LABEL_MAP = {FLOOR_RAW: "floor", CHAIR_RAW: "chair"}
FLOOR_Z = 1.3                                     # the scan's floor height before shifting, metres


def _room_mesh(n_chairs: int = 1):
    """A 4 x 4 m floor quad at z = FLOOR_Z with ``n_chairs`` 0.5 m boxes standing on it.
    Returns vertices (V, 3), triangles (F, 3), per-vertex raw labels, per-vertex instance ids."""
    verts = [np.array([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]], float)]
    tris = [np.array([[0, 1, 2], [0, 2, 3]])]
    labels, inst = [np.full(4, FLOOR_RAW)], [np.full(4, 0)]
    n = 4
    for k in range(n_chairs):
        v, t = box_mesh((-1.0 + 1.5 * k, 0.5, 0.25), (0.5, 0.5, 0.5))
        verts.append(v)
        tris.append(t + n)
        labels.append(np.full(8, CHAIR_RAW))
        inst.append(np.full(8, k + 1))
        n += 8
    v = np.concatenate(verts)
    v[:, 2] += FLOOR_Z
    return v, np.concatenate(tris), np.concatenate(labels), np.concatenate(inst)


def _write(path, verts, tris, vprops=None, fprops=None, text=False, face_lists=None):
    vdtype = [("x", "f4"), ("y", "f4"), ("z", "f4")] + [(k, a.dtype.str) for k, a in (vprops or {}).items()]
    vert = np.empty(len(verts), dtype=vdtype)
    vert["x"], vert["y"], vert["z"] = verts.T
    for k, a in (vprops or {}).items():
        vert[k] = a
    elements = [PlyElement.describe(vert, "vertex")]
    faces = face_lists if face_lists is not None else [list(t) for t in tris]
    if faces is not None:
        fdtype = [("vertex_indices", "O")] + [(k, a.dtype.str) for k, a in (fprops or {}).items()]
        face = np.empty(len(faces), dtype=fdtype)
        face["vertex_indices"] = [np.asarray(f, dtype=np.int32) for f in faces]
        for k, a in (fprops or {}).items():
            face[k] = a
        elements.append(PlyElement.describe(face, "face"))
    PlyData(elements, text=text).write(str(path))
    return path


@pytest.mark.parametrize("text", [True, False], ids=["ascii", "binary"])
def test_vertex_labels_colours_and_floor_shift(tmp_path, text):
    v, t, lab, _ = _room_mesh()
    rgb = np.where(lab[:, None] == CHAIR_RAW, [200, 20, 20], [90, 90, 90]).astype(np.uint8)
    path = _write(tmp_path / "room.ply", v, t, {"label": lab.astype(np.int32), "red": rgb[:, 0],
                                                  "green": rgb[:, 1], "blue": rgb[:, 2]}, text=text)
    s = load_labelled_ply(path, LABEL_MAP)
    assert s.name == "room" and len(s.triangles) == 2 + 12
    assert (s.tri_class[:2] == CLASS_ID["floor"]).all() and (s.tri_class[2:] == CLASS_ID["chair"]).all()
    assert s.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-5)           # floor shifted to z = 0
    assert s.meta["floor_offset_m"] == pytest.approx(FLOOR_Z, abs=1e-5)
    np.testing.assert_array_equal(s.tri_albedo[2], [200, 20, 20])
    np.testing.assert_array_equal(s.tri_albedo[0], [90, 90, 90])
    assert len(s.instance_ids(CLASS_ID["chair"])) == 1


def test_face_labels_and_instance_property(tmp_path):
    v, t, lab, inst = _room_mesh(n_chairs=2)
    face_lab = lab[t[:, 0]].astype(np.uint8)
    face_inst = np.array([7, 7] + [3] * 12 + [3] * 12, dtype=np.int32)   # one id spanning both chairs
    path = _write(tmp_path / "faces.ply", v, t, fprops={"label": face_lab, "objectId": face_inst})
    s = load_labelled_ply(path, LABEL_MAP)
    assert (s.tri_class == np.where(face_lab == CHAIR_RAW, CLASS_ID["chair"], CLASS_ID["floor"])).all()
    assert len(s.instance_ids(CLASS_ID["chair"])) == 1 and s.meta["instance_source"] == "objectId"
    face_inst[:2] = 3   # now the id spans floor and chairs: it must be split by class
    s2 = load_labelled_ply(_write(tmp_path / "mixed.ply", v, t, fprops={"label": face_lab, "objectId": face_inst}), LABEL_MAP)
    for i in s2.instance_ids():
        s2.instance_class(int(i))


def test_connected_components_make_instances(tmp_path):
    v, t, lab, _ = _room_mesh(n_chairs=3)
    s = load_labelled_ply(_write(tmp_path / "cc.ply", v, t, {"label": lab.astype(np.int16)}), LABEL_MAP)
    assert len(s.instance_ids(CLASS_ID["chair"])) == 3       # three separate boxes
    assert len(s.instance_ids(CLASS_ID["floor"])) == 1
    assert s.meta["instance_source"] == "components"


def test_majority_vote_per_face(tmp_path):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    t = np.array([[0, 1, 2], [1, 3, 2]])
    lab = np.array([FLOOR_RAW, CHAIR_RAW, CHAIR_RAW, FLOOR_RAW], np.int32)   # face 0: 1 floor vs 2 chair
    s = load_labelled_ply(_write(tmp_path / "vote.ply", v, t, {"label": lab}), LABEL_MAP)
    assert s.tri_class[0] == CLASS_ID["chair"] and s.tri_class[1] == CLASS_ID["chair"]


def test_y_up_is_rotated_to_z_up(tmp_path):
    v, t, lab, _ = _room_mesh()
    y_up = np.stack([v[:, 0], v[:, 2], -v[:, 1]], axis=1)   # inverse of the loader's rotation
    s = load_labelled_ply(_write(tmp_path / "yup.ply", y_up, t, {"label": lab.astype(np.int32)}), LABEL_MAP, up_axis="y")
    z_up = load_labelled_ply(_write(tmp_path / "zup.ply", v, t, {"label": lab.astype(np.int32)}), LABEL_MAP)
    np.testing.assert_allclose(s.vertices, z_up.vertices, atol=1e-5)
    chair = s.instance_triangles(int(s.instance_ids(CLASS_ID["chair"])[0])).reshape(-1, 3)
    assert chair[:, 2].max() == pytest.approx(0.5, abs=1e-5)   # the chair stands 0.5 m tall on the floor
    with pytest.raises(ValueError, match="up_axis"):
        load_labelled_ply(tmp_path / "zup.ply", LABEL_MAP, up_axis="up")


def test_quads_are_triangulated_and_float_colours(tmp_path):
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    f = np.ones(4, np.float32) * 0.5
    path = _write(tmp_path / "quad.ply", v, None, {"label": np.full(4, FLOOR_RAW, np.int32), "red": f, "green": f, "blue": f},
                  face_lists=[[0, 1, 2, 3]])
    s = load_labelled_ply(path, LABEL_MAP)
    assert len(s.triangles) == 2 and (s.tri_albedo == 128).all()


@pytest.mark.parametrize("fmt", ["json", "json_records", "tsv", "csv", "dict_str_keys"])
def test_label_map_sources(tmp_path, fmt):
    v, t, lab, _ = _room_mesh()
    lab = np.where(lab == CHAIR_RAW, 12, 3)   # ScanNet-like raw ids: 12 = "couch", 3 = "floor"
    path = _write(tmp_path / "s.ply", v, t, {"label": lab.astype(np.int32)})
    table = {3: "Floor", 12: "couch", 40: "otherprop"}
    if fmt == "json":
        (tmp_path / "m.json").write_text(json.dumps(table))
        label_map = tmp_path / "m.json"
    elif fmt == "json_records":
        (tmp_path / "m.json").write_text(json.dumps([{"id": k, "name": n} for k, n in table.items()]))
        label_map = str(tmp_path / "m.json")
    elif fmt in ("tsv", "csv"):
        sep = "\t" if fmt == "tsv" else ","
        rows = [sep.join(["id", "raw_category", "nyu40class"])] + [sep.join([str(k), "x", n]) for k, n in table.items()]
        (tmp_path / f"m.{fmt}").write_text("\n".join(rows) + "\n")
        label_map = tmp_path / f"m.{fmt}"
    else:
        label_map = {str(k): n for k, n in table.items()}
    s = load_labelled_ply(path, label_map)
    assert set(np.unique(s.tri_class)) == {CLASS_ID["floor"], CLASS_ID["sofa"]}   # synonyms resolved


def test_unmapped_labels_become_void_and_default_map_is_identity(tmp_path):
    v, t, lab, _ = _room_mesh()
    lab = np.where(lab == CHAIR_RAW, JUNK_RAW, lab)
    s = load_labelled_ply(_write(tmp_path / "j.ply", v, t, {"label": lab.astype(np.int32)}), LABEL_MAP)
    assert (s.tri_class[2:] == VOID).all() and (s.tri_instance[2:] == -1).all()
    ids = np.where(lab == JUNK_RAW, CLASS_ID["toilet"], CLASS_ID["floor"]).astype(np.int32)
    s = load_labelled_ply(_write(tmp_path / "ids.ply", v, t, {"label": ids}))   # no map: calnav ids
    assert (s.tri_class[2:] == CLASS_ID["toilet"]).all()


def test_errors(tmp_path):
    v, t, lab, _ = _room_mesh()
    with pytest.raises(SceneError, match="not found"):
        load_labelled_ply(tmp_path / "missing.ply", LABEL_MAP)
    (tmp_path / "junk.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\n"
                                        b"end_header\n\x00\x01")
    with pytest.raises(SceneError, match="corrupt"):
        load_labelled_ply(tmp_path / "junk.ply", LABEL_MAP)
    (tmp_path / "notply.ply").write_text("hello world\n")
    with pytest.raises(SceneError, match="corrupt"):
        load_labelled_ply(tmp_path / "notply.ply", LABEL_MAP)
    cloud = _write(tmp_path / "cloud.ply", v, None, {"label": lab.astype(np.int32)}, face_lists=[])
    with pytest.raises(SceneError, match="no faces"):
        load_labelled_ply(cloud, LABEL_MAP)
    nolab = _write(tmp_path / "nolab.ply", v, t, {"quality": lab.astype(np.float32)})
    with pytest.raises(SceneError, match=r"no 'label' property.*quality.*; name the one holding the labels in its "
                                         r'labels.json: \{"label_map": \{\.\.\.\}, "label_property": "\.\.\."\}$'):
        load_labelled_ply(nolab, LABEL_MAP)
    s = load_labelled_ply(nolab, LABEL_MAP, label_property="quality")   # float labels are accepted as ints
    assert CLASS_ID["chair"] in s.classes_present()
    path = _write(tmp_path / "ok.ply", v, t, {"label": lab.astype(np.int32)})
    with pytest.raises(SceneError, match="maps to a calnav class"):
        load_labelled_ply(path, {FLOOR_RAW: "spaceship", CHAIR_RAW: "unicorn"})
    with pytest.raises(SceneError, match="label map file not found"):
        load_labelled_ply(path, tmp_path / "nope.json")
    (tmp_path / "bad.tsv").write_text("foo\tbar\n1\t2\n")
    with pytest.raises(SceneError, match="id column"):
        load_labelled_ply(path, tmp_path / "bad.tsv")
    bad_idx = _write(tmp_path / "badidx.ply", v, np.array([[0, 1, 999]]), {"label": lab.astype(np.int32)})
    with pytest.raises(SceneError, match="out of range"):
        load_labelled_ply(bad_idx, LABEL_MAP)
