"""Finishing the approach to a detected goal: where the agent may STOP, and where it plans to.

The task counts a STOP on a *view point*: a navigable spot within the task's view-point radius
(``env.view_point_radius_m``, Habitat's 1.0 m) of the goal object from which the object is
visible. The agent's estimate on its 2D map is the *view region*: cells within ``reach`` of the
detected goal component whose straight line to their nearest goal cell crosses nothing that
hides it (the map's view-blocking cells: obstacles at about camera height, such as walls; a
coffee table does not hide a sofa) other than the object itself (its own cells and those within
``OBJECT_MARGIN_CELLS`` of them are its body, not something in the way). ``reach`` is the
view-point radius less ``agent.stop_margin_m`` (the map's error: goal cells are where the
object's surface was seen, the view points are measured from its footprint).

Planning aims at the traversable part of the view region, not at the goal's own cells (which
are inside the object and never reachable), so an approach ends as soon as it reaches a spot
the task would accept. All masks are (h, w) bool in the planning window's cells.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from calnav.agent.projection import dilate

OBJECT_MARGIN_CELLS = 3      # obstacle cells this close to the goal component belong to the object
LOS_SAMPLES_PER_CELL = 2     # line-of-sight samples per cell of distance


def view_region(goal: np.ndarray, blockers: np.ndarray, reach_cells: float) -> np.ndarray:
    """(h, w) bool: cells within ``reach_cells`` of the ``goal`` component whose segment to
    their nearest goal cell crosses no ``blockers`` cell outside the object (module docstring)."""
    if not goal.any():
        return np.zeros_like(goal)
    dist, idx = ndimage.distance_transform_edt(~goal, return_indices=True)
    cand = np.argwhere((dist <= reach_cells) & ~goal)
    out = goal.copy()
    if len(cand) == 0:
        return out
    target = np.stack([idx[0][cand[:, 0], cand[:, 1]], idx[1][cand[:, 0], cand[:, 1]]], axis=1)
    blocking = blockers & ~dilate(goal, OBJECT_MARGIN_CELLS)
    n = max(2, int(np.ceil(reach_cells * LOS_SAMPLES_PER_CELL)) + 1)
    t = np.linspace(0.0, 1.0, n)
    pts = np.rint(cand[:, None, :] + (target - cand)[:, None, :] * t[None, :, None]).astype(np.int64)
    clear = ~blocking[pts[..., 0], pts[..., 1]].any(axis=1)
    out[cand[clear, 0], cand[clear, 1]] = True
    return out


def nearest_cell(mask: np.ndarray, rc: tuple[int, int]) -> tuple[tuple[int, int], float]:
    """(nearest True cell of ``mask`` to ``rc``, its distance in cells); ``mask`` must hold one."""
    cells = np.argwhere(mask)
    d = np.hypot(*(cells - np.asarray(rc)).T)
    i = int(np.argmin(d))
    return (int(cells[i, 0]), int(cells[i, 1])), float(d[i])
