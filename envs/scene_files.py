"""Scene files by path: which kinds there are, finding them under a folder, loading any one (cached).

Kinds, told apart by their files (no format flag):

- ``*.npz``: a ``Scene.save`` file, read as it is.
- ``*.ply``: a labelled mesh (``envs.scan``), its settings from ``<stem>.labels.json`` or
  ``labels.json`` beside it: a plain ``{raw id: class name}`` map or ``{"label_map": {...},
  "up_axis": "y", "label_property": "label"}``.
- ``<id>.glb`` with ``<id>.house`` or ``<id>_semantic.ply`` beside it: an MP3D scene (``envs.mp3d``).
- any other ``<id>.glb`` / ``<id>.basis.glb``: an HM3D scene (``envs.hm3d``; semantics from
  ``<id>.semantic.glb`` + ``<id>.semantic.txt`` when present). ``<id>.semantic.glb`` is a
  semantic mesh, not a scene.

``load_scene_file(path)`` loads any of them; a converted PLY or GLB is cached at
``cache_dir()/scenes/user_<id>_<key>.npz``, ``key`` a hash of every input file's path, mtime and
size (the mesh, its semantic files, the scene dataset configs and label map found) and the
converter's version. Every cache file carries its identity (``converted_from``) and is checked on
load: a damaged one, or one holding another scene, is rebuilt (with a warning naming it).
Every scene file is checked as it loads, converted or cached, before anything sized by its extent
is built (``envs.scene_plausible``: a building in metres standing on its floor); the refusal
names the fix of the file's kind: a PLY's ``up_axis`` in its labels.json, a GLB's ``up`` in a
scene dataset config, the conversion to metres (no file calnav reads holds a scale).
``scene_files_in(folder)`` lists a folder's scenes by id; ``check_scene_usable`` refuses, in one
line, a scene that lacks the RGB or the semantics a command needs.
"""
from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path

import numpy as np

from calnav.common.atomic import atomic_path, is_temp_file
from calnav.envs.glb_scene import label_settings
from calnav.envs.hm3d import hm3d_files, load_hm3d_scene, scene_id_of
from calnav.envs.mp3d import load_mp3d_scene, mp3d_files
from calnav.envs.scan import UP_AXES, load_labelled_ply, up_axis_rotation
from calnav.envs.scene import RGB_UNAVAILABLE, SEMANTICS_UNAVAILABLE, Scene, SceneError, cache_dir
from calnav.envs.scene_frame import declare_frame, find_dataset_configs
from calnav.envs.scene_plausible import axis_name, check_plausible, frame_rotation, misreading

PLY_CONVERSION_VERSION = 2                  # converted-PLY cache key (2: meta closed_solids = False)
GLB_CONVERSION_VERSION = 3                  # converted HM3D / MP3D cache key (2: the winding decides walkability; 3: storeys)
SCENE_SUFFIXES = (".npz", ".ply", ".glb")
SEMANTIC_GLB_SUFFIX = ".semantic.glb"


def scene_kind(path: Path) -> str:
    """"npz" | "ply" | "hm3d" | "mp3d" of a scene file; SceneError naming the valid kinds."""
    name = path.name
    if name.endswith(SEMANTIC_GLB_SUFFIX):
        raise SceneError(f"{path} is an HM3D semantic mesh, not a scene: load "
                         f"{name[: -len(SEMANTIC_GLB_SUFFIX)]}.glb (or .basis.glb) beside it")
    if path.suffix not in SCENE_SUFFIXES:
        raise SceneError(f"{path}: unknown scene file type {path.suffix!r}; scene files are .npz (calnav scenes), "
                         ".ply (labelled meshes), .glb (HM3D / MP3D)")
    if path.suffix != ".glb":
        return path.suffix[1:]
    files = mp3d_files(path)
    return "mp3d" if files["house"] or files["semantic_ply"] else "hm3d"


def _ply_label_file(ply: Path) -> Path | None:
    """The PLY's sibling label file: ``<stem>.labels.json``, else ``labels.json``; None if neither."""
    return next((c for c in (ply.with_name(ply.stem + ".labels.json"), ply.with_name("labels.json")) if c.exists()),
                None)


def _ply_settings(ply: Path) -> dict:
    """load_labelled_ply keyword arguments from the PLY's sibling label file, if any."""
    cand = _ply_label_file(ply)
    if cand is None:
        return {}
    try:
        data = json.loads(cand.read_text())
    except ValueError as exc:
        raise SceneError(f"unreadable label file {cand}: {exc}") from exc
    if isinstance(data, dict) and "label_map" in data:
        unknown = set(data) - {"label_map", "up_axis", "label_property"}
        if unknown:
            raise SceneError(f"{cand}: unknown keys {sorted(unknown)}; valid: label_map, up_axis, label_property")
        return dict(data)
    return {"label_map": data}


def refuse_implausible(scene: Scene, kind: str, path: Path) -> None:
    """SceneError (one line) when the scene loaded from ``path`` ("npz" | "ply" | "hm3d" | "mp3d"
    ``kind``) is no building in metres on its floor (``envs.scene_plausible``), naming the fix:
    the up axis to declare, in the file's coordinates, or the conversion to metres."""
    found = check_plausible(scene.vertices, scene.triangles, scene.tri_class)
    if found is None:
        return
    if found.scale is not None:
        how = ("Scene.vertices * {s}, then Scene.save" if kind == "npz" else
               "every vertex coordinate x {s}, in the tool that wrote it or e.g. trimesh's apply_scale({s})")
        raise SceneError(f"{path}: {found.problem}; calnav has no scale setting: convert the file to metres "
                         f"({how.format(s=found.scale)})")
    if kind == "ply":
        rot, read_with = up_axis_rotation(scene.meta["up_axis"]), ""
    elif kind in ("hm3d", "mp3d"):
        frame = scene.meta["frame"]
        rot, read_with = frame_rotation(frame["up"], frame["front"]), f" (read with up {frame['up']} from {frame['source']})"
    else:   # a calnav scene file: read as it is
        rot, read_with = np.eye(3), ""
    up = rot.T @ found.up   # the direction that should be +z, in the file's coordinates
    if kind == "ply":
        label_file = _ply_label_file(path) or path.with_name(path.stem + ".labels.json")
        fix = (f'set "up_axis": "{axis_name(up)}" in {label_file} ({{"label_map": {{...}}, "up_axis": '
               f'"{axis_name(up)}"}}; up_axis is one of {", ".join(UP_AXES)})')
    elif kind in ("hm3d", "mp3d"):
        fix = declare_frame(up)
    else:
        fix = f"rotate its vertices so that its {axis_name(up)} axis is +z, then Scene.save"
    raise SceneError(f"{path}{read_with}: {misreading(up, rot.T @ [0.0, 0.0, 1.0])}: {found.problem}; {fix}")


def _stat_key(paths: list[Path]) -> list:
    return [[str(p.resolve()), p.stat().st_mtime_ns, p.stat().st_size] for p in paths]


def _glb_inputs(path: Path, kind: str, root: Path | None, config: Path | None) -> list[Path]:
    """Every file the conversion of the GLB scene ``path`` reads, the render mesh first."""
    if kind == "hm3d":
        files = hm3d_files(path)
        scene_id, inputs = scene_id_of(path), [files["render"], files["semantic_glb"], files["semantic_txt"]]
    else:
        files = mp3d_files(path)
        scene_id, inputs = path.stem, [path, files["house"], files["semantic_ply"]]
    inputs += [config] if config is not None else find_dataset_configs(path, root)
    inputs.append(label_settings(path, scene_id, root)[1])
    return [p for p in inputs if p is not None]


def scene_file_inputs(path: Path, root: Path | None = None, dataset_config: Path | None = None) -> list:
    """[path, mtime ns, size] of every file the scene ``path`` is read from (the mesh, its
    semantic files, scene dataset configs -- ``dataset_config`` when one is named --, label
    files): what keys a scene read in memory (``envs.scenes``), so that an edited
    ``.semantic.txt`` is read again."""
    kind = scene_kind(path)
    if kind == "npz":
        return _stat_key([path])
    if kind == "ply":
        return _stat_key([p for p in (path, _ply_label_file(path)) if p is not None])
    return _stat_key(_glb_inputs(path, kind, root, dataset_config))


def load_scene_file(path: str | Path, root: str | Path | None = None, dataset_config: str | Path | None = None) -> Scene:
    """The scene in ``path`` (.npz, labelled .ply, HM3D or MP3D .glb; see the module docstring).

    root: the scene directory the file was found under (the highest folder searched for a scene
    dataset config and a label map; None: every folder above the file). dataset_config: an
    explicit ``*.scene_dataset_config.json`` for a GLB (e.g. the one an episode file names).
    SceneError in one line for a missing or unusable file."""
    path = Path(path)
    root = Path(root) if root is not None else None
    config = Path(dataset_config) if dataset_config is not None else None
    kind = scene_kind(path)
    if not path.is_file():
        raise SceneError(f"scene file not found: {path}")
    if kind == "npz":
        scene = Scene.load(path)
        refuse_implausible(scene, kind, path)
        return scene
    if kind == "ply":
        settings = _ply_settings(path)
        st = path.stat()
        key = hashlib.sha1(json.dumps([PLY_CONVERSION_VERSION, str(path.resolve()), st.st_mtime_ns, st.st_size,
                                       settings], sort_keys=True, default=str).encode()).hexdigest()[:12]
        identity = {"converted_from": {"ply": str(path.resolve()), "key": key}}
        scene_id = path.stem
        convert = lambda: load_labelled_ply(path, name=scene_id, **settings)  # noqa: E731
        finish = lambda scene: scene  # noqa: E731
    else:
        scene_id = scene_id_of(path) if kind == "hm3d" else path.stem
        inputs = _glb_inputs(path, kind, root, config)
        key = hashlib.sha1(json.dumps([GLB_CONVERSION_VERSION, kind, _stat_key(inputs)]).encode()).hexdigest()[:12]
        # the render file, not the path asked for: <id>.basis.glb and <id>.glb beside it are one scene
        identity = {"converted_from": {kind: str(inputs[0].resolve()), "key": key}}
        loader = load_hm3d_scene if kind == "hm3d" else load_mp3d_scene
        convert = lambda: loader(path, root=root, config=config, name=scene_id)  # noqa: E731
        finish = with_storeys
    cached = cache_dir() / "scenes" / f"user_{scene_id}_{key}.npz"
    scene = cached_scene(cached, identity)
    fresh = scene is None
    if fresh:
        scene = convert()
    refuse_implausible(scene, kind, path)   # a cache older than the check is checked too
    if fresh:
        scene = finish(scene)
        scene.meta.update(identity)
        save_atomic(scene, cached)
    return scene


def with_storeys(scene: Scene) -> Scene:
    """``scene`` with the storeys its geometry holds in its meta (``envs.storey_detect``), so that
    a scan with stairs gets one navigation layer per storey."""
    from calnav.envs.storey_detect import storey_meta

    scene.meta.update(storey_meta(scene))
    return scene


def scene_files_in(folder: Path) -> dict[str, Path]:
    """{scene id: file} of the scenes in ``folder``: its ``*.ply`` / ``*.npz`` (the id is the
    stem; ``.npz`` wins over ``.ply``) and the HM3D / MP3D ``.glb`` scenes anywhere below it
    (the id is the scene's: ``TEEsavR23oF``; a ``.glb`` beside a ``.basis.glb`` is the one listed;
    an id found twice, as HM3D's minival repeats val scenes, is the first in path order)."""
    files: dict[str, Path] = {}
    for p in sorted(folder.rglob("*.glb")):
        if is_temp_file(p) or p.name.endswith(SEMANTIC_GLB_SUFFIX):
            continue
        sid = scene_id_of(p)
        held = files.get(sid)
        if held is None or (held.parent == p.parent and held.name.endswith(".basis.glb")):
            files[sid] = p
    for p in sorted(folder.glob("*.ply")) + sorted(folder.glob("*.npz")):
        if not is_temp_file(p):
            files[p.stem] = p
    return files


def check_scene_usable(scene: Scene, needs_rgb: bool = False, needs_semantics: bool = False,
                       what: str = "this run") -> None:
    """SceneError (one line, the scene's recorded reason and the fix) when ``what`` needs RGB or
    ground-truth semantics the scene's source could not provide."""
    for needed, key, kind in ((needs_rgb, RGB_UNAVAILABLE, "RGB"), (needs_semantics, SEMANTICS_UNAVAILABLE,
                                                                     "ground-truth semantics")):
        if needed and scene.meta.get(key):
            raise SceneError(f"{what} needs {kind}, which scene {scene.name!r} lacks: {scene.meta[key]}")


def cached_scene(path: Path, identity: dict) -> Scene | None:
    """The scene cached at ``path`` when it is readable and its metadata holds ``identity``;
    None (rebuild it) when it is missing, damaged, or another scene's (with a warning naming the
    file and the first field that differs)."""
    if not path.exists():
        return None
    try:
        scene = Scene.load(path)
    except SceneError:
        return None   # a corrupt cache entry (a killed writer): rebuilt
    for key, want in identity.items():
        held = scene.meta.get(key)
        if held != want:
            warnings.warn(f"scene cache {path} holds another scene ({key} {_short(held)}, expected {_short(want)}); "
                          "rebuilding it")
            return None
    return scene


def _short(value, limit: int = 60) -> str:
    """``repr(value)``, or a placeholder when it is too long for a one-line warning (a settings dict)."""
    text = repr(value)
    return text if len(text) <= limit else "other settings"


def save_atomic(scene: Scene, path: Path) -> None:
    """Save under a unique temporary name, then rename: concurrent workers never see half a file."""
    try:
        with atomic_path(path) as tmp:
            scene.save(tmp)
    except OSError as exc:   # a read-only cache only costs speed
        warnings.warn(f"could not cache scene at {path}: {exc}")
