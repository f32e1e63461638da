"""Whether a scene is a building in metres standing on its floor: checked once per scene file as
it loads (``envs.scene_files.load_scene_file``), on its vertices and labels alone, before anything
sized by its extent (navmesh grids, rasters, voxel maps) is allocated.

Units
    A horizontal extent above ``MAX_EXTENT_M`` or a height above ``MAX_HEIGHT_M`` is no building
    in metres: a house 15 m across in centimetres spans 1.5 km, and a 0.05 m navmesh grid over it
    would take tens of GB. The likely unit is the one (centimetres: scale 0.01, millimetres:
    0.001) that brings the extent nearest a house's (``TYPICAL_HOUSE_M`` across,
    ``TYPICAL_HEIGHT_M`` high; the sum of the two log ratios).
Up axis
    In a valid frame at least ``MIN_HORIZONTAL_FLOOR`` of the labelled floor's area is
    horizontal (normals within 30 degrees of z), most of the labelled furniture's area (every
    non-structure class) lies above its nearest floor level (a storey's floor: a height holding
    ``MIN_LEVEL_SHARE`` of the floor's area), and the labelled ceiling's median height lies above
    the lowest floor (``floor_height``). A vertical floor says which axis is up (the one its
    normals lie along, pointing the way the furniture stands); furniture or a ceiling below the
    floor says the scene is upside down. Scenes without a labelled floor (or without furniture
    and ceiling) cannot tell, and pass.

``check_plausible(verts, tris, tri_class)`` returns the first problem (``Implausible``: what is
wrong, and the scale or the up vector that would fix it) or None; the loader turns it into a
one-line refusal naming the key (or conversion) that fixes the file. ``frame_rotation`` is the
rotation a declared up / front gives, shared by the GLB stage frames and a PLY's ``up_axis``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calnav.envs.semantics import CLASS_ID, STRUCTURE_IDS, VOID

MAX_EXTENT_M = 200.0        # horizontal extent above any house's (HM3D's and MP3D's largest are ~50 m), metres
MAX_HEIGHT_M = 100.0        # height above any house's (HM3D's four-storey scenes are ~15 m), metres
TYPICAL_HOUSE_M = 15.0      # a house's horizontal extent, for guessing the unit, metres
TYPICAL_HEIGHT_M = 5.0      # ... and its height (one or two storeys), metres
UNITS = ((0.01, "centimetres"), (0.001, "millimetres"))   # (scale to metres, unit) guessed for an oversized scene
HORIZONTAL_COS = np.cos(np.deg2rad(30.0))   # a floor face tilted less than 30 degrees counts as horizontal
MIN_HORIZONTAL_FLOOR = 0.5                  # share of floor area that must be horizontal in a valid frame
LEVEL_BIN_M = 0.1           # height bins of the floor levels, metres
MIN_LEVEL_SHARE = 0.05      # a floor level holds at least this share of the labelled floor's area
MOSTLY = 0.5                # share of the furniture's area that must stand above its nearest floor level
FLOOR_PERCENTILE = 2.0      # floor height = this percentile of floor-vertex z (robust to stray points), percent
AXES = ("x", "y", "z")


@dataclass(frozen=True)
class Implausible:
    """Why a scene is no building in metres on its floor: ``problem`` (text), and the fix:
    ``scale`` (multiply the coordinates by it) or ``up`` (3,) the direction, in the checked
    coordinates, that should be +z."""

    problem: str
    scale: float | None = None
    up: np.ndarray | None = None


def frame_rotation(up, front) -> np.ndarray:
    """(3, 3) float64 rotation taking ``up`` (3,) to +z, ``front`` (3,) to +y and front x up to +x."""
    up = np.asarray(up, dtype=np.float64)
    front = np.asarray(front, dtype=np.float64)
    up, front = up / np.linalg.norm(up), front / np.linalg.norm(front)
    return np.stack([np.cross(front, up), front, up])


def default_front(up) -> list[float]:
    """A front for ``up``: glTF's -z for a y-up file, +y otherwise (HM3D's)."""
    return [0.0, 0.0, -1.0] if abs(np.asarray(up, dtype=np.float64)[1]) > 0.5 else [0.0, 1.0, 0.0]


def axis_name(v) -> str:
    """'x' | '-x' | 'y' | ... of the coordinate axis nearest the direction ``v`` (3,)."""
    v = np.asarray(v, dtype=np.float64)
    k = int(np.argmax(np.abs(v)))
    return ("-" if v[k] < 0 else "") + AXES[k]


def axis_vector(name: str) -> np.ndarray:
    """(3,) unit vector of an axis name ('z', '-y', ...)."""
    return (-1.0 if name.startswith("-") else 1.0) * np.eye(3)[AXES.index(name.lstrip("-"))]


def floor_height(verts: np.ndarray, tris: np.ndarray, tri_class: np.ndarray) -> float:
    """The floor's height, metres: the ``FLOOR_PERCENTILE`` percentile of the z of the vertices of
    floor-class faces (of all vertices when no face is floor). verts (V, 3) z-up, tris (F, 3),
    tri_class (F,)."""
    floor_faces = tri_class == CLASS_ID["floor"]
    floor_vz = verts[np.unique(tris[floor_faces]), 2] if floor_faces.any() else verts[:, 2]
    return float(np.percentile(floor_vz, FLOOR_PERCENTILE))


def _floor_levels(height: np.ndarray, area: np.ndarray) -> np.ndarray:
    """(L,) the heights holding at least ``MIN_LEVEL_SHARE`` of the floor's area (``LEVEL_BIN_M``
    bins; bin centres), of floor faces at ``height`` (F,) with ``area`` (F,): the storeys' floors,
    not a stair tread or a stray floor label."""
    bins = np.floor((height - height.min()) / LEVEL_BIN_M).astype(np.int64)
    per_bin = np.bincount(bins, weights=area)
    keep = np.flatnonzero(per_bin >= MIN_LEVEL_SHARE * per_bin.sum())
    return height.min() + (keep + 0.5) * LEVEL_BIN_M


def _stands_above(verts: np.ndarray, tris: np.ndarray, tri_class: np.ndarray, axis: int) -> bool | None:
    """Whether the labelled furniture and ceiling stand above the labelled floor along ``axis``
    of ``verts`` (V, 3); None when there is no floor, or neither furniture nor ceiling, to tell.
    Furniture: most of its area (``MOSTLY``) lies above its nearest floor level (``_floor_levels``:
    each storey's, so a house upside down is told storey by storey). Ceiling: its median face
    height lies above the lowest floor (``floor_height``)."""
    floor = tri_class == CLASS_ID["floor"]
    if not floor.any():
        return None
    v = verts[tris]
    height = v[:, :, axis].mean(axis=1)
    area = np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1) / 2
    above = []
    furniture = (tri_class != VOID) & ~np.isin(tri_class, STRUCTURE_IDS)
    if furniture.any() and area[furniture].sum() > 0:
        levels = _floor_levels(height[floor], area[floor])
        nearest = levels[np.argmin(np.abs(height[furniture, None] - levels[None, :]), axis=1)]
        above.append(area[furniture][height[furniture] > nearest].sum() >= MOSTLY * area[furniture].sum())
    ceiling = tri_class == CLASS_ID["ceiling"]
    if ceiling.any():
        base = floor_height(verts[:, [0, 1, axis]], tris, tri_class)
        above.append(float(np.median(height[ceiling])) > base)
    return all(above) if above else None


def _units(verts: np.ndarray) -> Implausible | None:
    size = verts.max(axis=0) - verts.min(axis=0)
    across = float(max(size[0], size[1]))
    if across <= MAX_EXTENT_M and size[2] <= MAX_HEIGHT_M:
        return None
    def misfit(unit: tuple[float, str]) -> float:
        return float(sum(abs(np.log(max(m, 1e-9) * unit[0] / typical))
                         for m, typical in ((across, TYPICAL_HOUSE_M), (size[2], TYPICAL_HEIGHT_M))))

    scale, unit = min(UNITS, key=misfit)
    return Implausible(f"it is {size[0]:.0f} x {size[1]:.0f} m across and {size[2]:.0f} m high, beyond any building "
                       f"(> {MAX_EXTENT_M:.0f} m across or > {MAX_HEIGHT_M:.0f} m high): its coordinates are likely "
                       f"{unit} (scale {scale}), and calnav reads them as metres", scale=scale)


def check_plausible(verts: np.ndarray, tris: np.ndarray, tri_class: np.ndarray) -> Implausible | None:
    """The first reason (units, then up axis; module docstring) the scene ``verts`` (V, 3) z-up,
    ``tris`` (F, 3), ``tri_class`` (F,) is no building in metres on its floor; None when it is."""
    verts = np.asarray(verts, dtype=np.float64)
    found = _units(verts)
    if found is not None:
        return found
    floor = tri_class == CLASS_ID["floor"]
    if floor.any():
        v = verts[tris[floor]]
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])   # |n| = 2 x area: area-weighted by construction
        area = np.linalg.norm(n, axis=1)
        flat = np.abs(n[:, 2]) >= HORIZONTAL_COS * area
        if area.sum() > 0 and area[flat].sum() < MIN_HORIZONTAL_FLOOR * area.sum():
            axis = int(np.argmax(np.abs(n).sum(axis=0)))
            up = np.eye(3)[axis]
            if _stands_above(verts, tris, tri_class, axis) is False:
                up = -up
            return Implausible(f"its labelled floor is not horizontal (it faces the {AXES[axis]} axis)", up=up)
    if _stands_above(verts, tris, tri_class, 2) is False:
        return Implausible("its labelled furniture or ceiling lies below its floor", up=np.array([0.0, 0.0, -1.0]))
    return None


def misreading(found_up, read_up) -> str:
    """How a file was misread: 'upside down (z flipped)' when its up is the opposite of the one
    it was read with, else e.g. 'y-up read as z-up'. Both (3,) in file coordinates."""
    found, read = axis_name(found_up), axis_name(read_up)
    if found.lstrip("-") == read.lstrip("-"):
        return f"upside down ({read.lstrip('-')} flipped)"
    return f"{found}-up read as {read}-up"
