"""The frame of a habitat-style scene file: its ``*.scene_dataset_config.json``, the rotation into
calnav's world frame, and the check that the result stands on its floor.

habitat-sim places a stage by its ``up`` and ``front`` vectors (``stages.default_attributes`` of a
scene dataset config; ``geo::CoordinateFrame``): file ``up`` becomes habitat's +y, file ``front``
habitat's -z. Habitat's world is (x, z, -y) of calnav's, so file ``up`` becomes calnav's +z, file
``front`` calnav's +y and ``front x up`` calnav's +x. HM3D's configs declare up [0, 0, 1], front
[0, 1, 0]: their GLB coordinates are calnav's frame unchanged. A ``.glb`` without a config gets
habitat-sim's own default for ``.glb`` stages, the same z-up frame
(``StageAttributesManager::setDefaultAssetNameBasedAttributes``, written for MP3D), not glTF's y-up:
that keeps calnav's frame the one habitat-lab's episodes were generated in.

``find_dataset_configs`` looks for configs in the scene's folder and each folder above it (up to
``root`` when given); the nearest folder holding any wins. ``place_on_floor`` rotates a labelled
mesh into calnav's frame and shifts the floor to z = 0 (``envs.scene_plausible.floor_height``);
whether the frame leaves the scene standing on its floor is ``envs.scene_plausible``'s check,
whose refusal names the ``up`` / ``front`` to declare (``declare_frame``).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calnav.envs.scene import SceneError
from calnav.envs.scene_plausible import default_front, floor_height, frame_rotation

CONFIG_SUFFIX = ".scene_dataset_config.json"


@dataclass(frozen=True)
class SceneFrame:
    """A stage's orientation: ``up`` and ``front`` (3,) in file coordinates, where they came from
    (``source``: a config path or habitat-sim's default) and the config's ``has_semantic_textures``
    (None when no config says)."""

    up: tuple[float, float, float]
    front: tuple[float, float, float]
    source: str
    has_semantic_textures: bool | None = None

    def rotation(self) -> np.ndarray:
        """(3, 3) float64 calnav-from-file rotation: up -> +z, front -> +y, front x up -> +x."""
        return frame_rotation(self.up, self.front)


HABITAT_GLB_DEFAULT = SceneFrame(up=(0.0, 0.0, 1.0), front=(0.0, 1.0, 0.0),
                                 source="habitat-sim's default frame for .glb stages (no scene dataset config)")


def _vector(value, key: str, path: Path) -> tuple[float, float, float]:
    try:
        vec = tuple(float(x) for x in value)
    except (TypeError, ValueError):
        vec = ()
    if len(vec) != 3 or not np.isfinite(vec).all() or np.linalg.norm(vec) == 0:
        raise SceneError(f"{path}: stages.default_attributes.{key} must be a non-zero [x, y, z], got {value!r}")
    return vec  # type: ignore[return-value]


def read_dataset_config(path: str | Path) -> SceneFrame:
    """The stage frame a habitat-sim scene dataset config declares (``stages.default_attributes``
    ``up`` / ``front``; habitat-sim's ``.glb`` default for a missing one) and its
    ``has_semantic_textures``. SceneError for unreadable JSON or an invalid frame."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise SceneError(f"unreadable scene dataset config {path}: {exc}") from None
    if not isinstance(doc, dict):
        raise SceneError(f"{path}: a scene dataset config is a JSON object with a 'stages' entry")
    attrs = (doc.get("stages") or {}).get("default_attributes") or {}
    up = _vector(attrs["up"], "up", path) if "up" in attrs else HABITAT_GLB_DEFAULT.up
    front = _vector(attrs["front"], "front", path) if "front" in attrs else HABITAT_GLB_DEFAULT.front
    if abs(np.dot(up, front)) > 1e-6 * np.linalg.norm(up) * np.linalg.norm(front):
        raise SceneError(f"{path}: up {list(up)} and front {list(front)} are not orthogonal (habitat-sim requires it)")
    flag = attrs.get("has_semantic_textures")
    return SceneFrame(up=up, front=front, source=str(path), has_semantic_textures=None if flag is None else bool(flag))


def find_dataset_configs(scene_file: Path, root: Path | None = None) -> list[Path]:
    """The ``*.scene_dataset_config.json`` of the nearest folder holding any, from the scene
    file's folder up to ``root`` (inclusive; the filesystem root when None)."""
    folder = scene_file.resolve().parent
    stop = root.resolve() if root is not None else None
    while True:
        found = sorted(folder.glob(f"*{CONFIG_SUFFIX}"))
        if found:
            return found
        if folder == stop or folder.parent == folder:
            return []
        folder = folder.parent


def scene_frame(scene_file: Path, root: Path | None = None, config: Path | None = None) -> SceneFrame:
    """The frame of ``scene_file``: the explicit ``config``, else the configs found by
    ``find_dataset_configs`` (several in one folder must agree on the frame), else
    ``HABITAT_GLB_DEFAULT``."""
    if config is not None:
        if not Path(config).is_file():
            raise SceneError(f"scene dataset config not found: {config}")
        return read_dataset_config(config)
    frames = [read_dataset_config(p) for p in find_dataset_configs(scene_file, root)]
    if not frames:
        return HABITAT_GLB_DEFAULT
    distinct = {(f.up, f.front) for f in frames}
    if len(distinct) > 1:
        listed = "; ".join(f"{Path(f.source).name}: up {list(f.up)} front {list(f.front)}" for f in frames)
        raise SceneError(f"{scene_file}: the scene dataset configs beside it declare different frames ({listed}); "
                         "keep one, or pass the config explicitly")
    flags = {f.has_semantic_textures for f in frames} - {None}
    return SceneFrame(up=frames[0].up, front=frames[0].front, source=", ".join(f.source for f in frames),
                      has_semantic_textures=(True in flags) if flags else None)


def declare_frame(up) -> str:
    """How to declare the file up ``up`` (3,) for a GLB scene: the scene dataset config to write."""
    up_list = [float(x) + 0.0 for x in up]   # + 0.0: no -0.0 in the message
    return (f'declare it in a {CONFIG_SUFFIX} beside the scene ("stages": {{"default_attributes": {{"up": {up_list}, '
            f'"front": {default_front(up)}}}}}; envs.hm3d_write.write_scene_dataset_config(folder, up=..., front=...))')


def place_on_floor(verts_file: np.ndarray, tris: np.ndarray, tri_class: np.ndarray,
                   frame: SceneFrame) -> tuple[np.ndarray, float]:
    """(vertices (V, 3) float64 in calnav's frame with the floor at z = 0, the floor's height
    before the shift in metres). verts_file (V, 3) file coordinates, tris (F, 3), tri_class (F,)."""
    verts = verts_file @ frame.rotation().T
    floor_z = floor_height(verts, tris, tri_class)
    verts[:, 2] -= floor_z
    return verts, floor_z
