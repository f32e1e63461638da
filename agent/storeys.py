"""Houses with storeys for the PEANUT-like agent (``env.dataset.storeys > 1``), from Habitat's
sensors only: gps is 2-D, so the agent finds the height of the floor it stands on itself.

Floor height. Each frame's depth is back-projected with the camera at the tracked floor
height + ``env.camera_height_m`` (the camera is level: the agent never tilts). Per map cell,
the lowest point at most ``ELEVATION_REACH_M`` above the agent's floor is that cell's floor
(``Storey.elev``: the ground, a stair tread, a sofa seat; a table top lies higher). After a move
the agent's floor is the median floor of the cells under it, when it is within ``FLOOR_STEP_M``
of the last one (one stair rise per 0.25 m step; the camera saw those cells from behind). Going
down a flight the treads just past the edge stay hidden under it: there the floor is
interpolated between the last floor and the first floor seen ahead (``floor_ahead``).

Obstacles, relative to the local floor (a step is not an obstacle): a cell is an obstacle when
its highest point up to the camera's height lies ``agent.obstacle_min_height_m`` above its
floor (the storey's floor where the cell's own is unseen), or when its floor lies more than
``STEP_M`` above a 4-neighbour's (the edge of a seat, a drop at a slab's edge); the cells the
agent stood on are free. This replaces the single-storey rule (points 0.25 m above z = 0),
which would make every tread beyond the second an obstacle.

Storeys: one 2-D map (and 3-D voxel map) per storey. The agent is on another storey once its
floor lies ``STOREY_SWITCH_M`` from the current storey's (part-way up a flight of stairs); it
returns to a storey it knows within that height, or starts a new one. A storey's floor is
where the agent first stood on it, raised (lowered) to the highest (lowest) floor it stands
on after climbing (descending) into it. Only points within ``STOREY_BAND_M`` of a storey's
floor are fused into its semantic map, so an object seen through a stair opening does not
turn up on the wrong storey.

Stairs: free cells whose floor lies ``STAIR_MIN_M`` or more above or below the storey's. When
no frontier is left on the current storey the agent heads for them; once on them it commits:
it keeps heading for the free cells above (below) its floor, turning to look when it knows
none, until a flat floor with none left ends the climb (``StoreyPeanutAgent``, ``agent.policy``).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calnav.agent import projection as pj
from calnav.agent.semantic_map import NUM_CHANNELS, FusedMapBuilder, MapChannels, MapState
from calnav.mapping.voxel_map import SemanticVoxelMap

ELEVATION_REACH_M = 0.6     # floor candidates: points at most this above the agent's floor, metres (a table top is not)
STEP_M = 0.22               # a cell whose floor is this much above a neighbour's is an edge, metres (navmesh climb 0.2)
FLOOR_STEP_M = 0.35         # the floor under the agent changes by at most this per action, metres (a rise + noise)
FOOTPRINT_M = 0.1           # the floor under the agent: the median over this radius, metres
FLAT_M = 0.03               # a cell whose floor points lie within this of each other is flat (registers), metres
REGISTER_BELOW_CAMERA_M = 0.1  # frames register on flat surfaces at least this below the camera, metres
REGISTER_GATE_M = 0.35        # ... on surfaces within this of their height on the map (two rises), metres
REGISTER_MIN_CELLS = 30     # a frame's height is registered on at least this many cells seen before
AHEAD_M = 2.5               # unseen floor under the agent: interpolated toward the seen floor this far ahead, metres
STOREY_SWITCH_M = 1.2       # another storey once the floor is this far from the current one's, metres (< half a storey)
STAIR_MIN_M = 0.08          # a free cell this far above / below the storey's floor is stairs, metres
FLIGHT_M = 0.6              # a first step leads to a flight when a second step lies within this, metres
STOREY_BAND_M = (-0.5, 2.4)  # fused into a storey's semantic map: points this far from its floor, metres
OFF_FLOOR_M = 0.15          # a seen floor this far from the storey's is another level (stairs, a landing), metres
OFF_FLOOR_MARGIN_M = 0.5    # ... and the cells this near it are not explored either (a stairwell's unseen treads), metres


@dataclass
class Storey:
    """One storey's maps. state: its 2-D map and voxel map (``MapState``); elev (n, n) float32
    floor height of each cell, metres (NaN unseen); top (n, n) float32 highest point up to the
    camera's height seen in each cell, metres (-inf none); stood (n, n) bool cells the agent's
    footprint covered; reg (n, n) float32 height of the flat surface (``FLAT_M``) below the camera
    last seen in each cell, metres (NaN none: what frames register on); z_ref: the storey's floor height, metres; direction: +1 entered
    climbing, -1 descending, 0 the start storey."""

    state: MapState
    elev: np.ndarray
    top: np.ndarray
    stood: np.ndarray
    reg: np.ndarray
    z_ref: float
    direction: int = 0

    @classmethod
    def new(cls, state: MapState, z_ref: float, direction: int) -> "Storey":
        n = state.size
        return cls(state, np.full((n, n), np.nan, np.float32), np.full((n, n), -np.inf, np.float32),
                   np.zeros((n, n), bool), np.full((n, n), np.nan, np.float32), float(z_ref), direction)

    def inherit(self, other: "Storey", floor_z: float) -> "Storey":
        """Seed this new storey, met part-way up (down) a flight at floor ``floor_z`` metres,
        with what ``other``, the storey it was reached from, knows there: every flat surface
        frames register on (one at another height fails the register gate) and the floors
        within ``STOREY_SWITCH_M`` of ``floor_z`` (the flight, the landing), with what stands
        on them. An empty map would give the next frames nothing to register on, and the floor
        read ahead instead may be the storey below, seen down the stairwell. Returns self."""
        self.reg[:] = other.reg
        with np.errstate(invalid="ignore"):
            near = np.abs(other.elev - floor_z) <= STOREY_SWITCH_M
        self.elev[near], self.top[near] = other.elev[near], other.top[near]
        return self

    def floor_under(self, rc: tuple[int, int], radius_cells: float) -> float | None:
        """Median floor height of the cells within ``radius_cells`` of ``rc``, or None unseen."""
        off = pj.disc_offsets(radius_cells) + rc
        off = off[((off >= 0) & (off < self.state.size)).all(axis=1)]
        z = self.elev[off[:, 0], off[:, 1]]
        z = z[np.isfinite(z)]
        return float(np.median(z)) if len(z) else None

    def off_floor(self, window: tuple[slice, slice], cell_m: float) -> np.ndarray:
        """(n, n) bool: the cells of ``window`` within ``OFF_FLOOR_MARGIN_M`` of a seen floor
        ``OFF_FLOOR_M`` or more from the storey's (stairs, a landing between storeys, a seat
        top): not explored from this storey. A frontier in a stairwell would walk the agent off
        the storey it explores; the stairs are taken by a climb (``agent.storey_policy``)."""
        out = np.zeros((self.state.size, self.state.size), bool)
        with np.errstate(invalid="ignore"):
            out[window] = pj.dilate(np.abs(self.elev[window] - self.z_ref) >= OFF_FLOOR_M, OFF_FLOOR_MARGIN_M / cell_m)
        return out

    def flights(self, free: np.ndarray, window: tuple[slice, slice], direction: int, cell_m: float) -> np.ndarray:
        """(h, w) bool: the first steps of flights up (``direction`` +1) or down (-1) from the
        storey's floor, the ``next_steps`` within ``FLIGHT_M`` of a floor a second step further
        (a low platform is one step and no more)."""
        first = self.next_steps(free, window, self.z_ref, direction)
        if not first.any():
            return first
        with np.errstate(invalid="ignore"):
            d = direction * (self.elev[window] - self.z_ref)
            second = (d >= 2 * STAIR_MIN_M + STEP_M / 2) & (d <= 3 * STEP_M)
        return first & pj.dilate(second, FLIGHT_M / cell_m)

    def next_steps(self, free: np.ndarray, window: tuple[slice, slice], floor_z: float, direction: int,
                   any_lower: bool = False) -> np.ndarray:
        """(h, w) bool: the free cells of ``window`` one step above (``direction`` +1) or below
        (-1) the floor at ``floor_z`` metres: a floor at least ``STAIR_MIN_M`` and at most
        ``STEP_M`` + ``STAIR_MIN_M`` away (a raised seat or bed is more than a step up and is not
        one; a flight is, one tread at a time). ``any_lower``: going down, every seen floor
        below counts (the treads just below the edge hide under it; the landing does not)."""
        with np.errstate(invalid="ignore"):
            d = direction * (self.elev[window] - floor_z)
            if any_lower and direction < 0:
                return free & (d >= STAIR_MIN_M)
            return free & (d >= STAIR_MIN_M) & (d <= STEP_M + STAIR_MIN_M)


def floor_ahead(storey: Storey, prev_xy: np.ndarray, xy: np.ndarray, prev_z: float, cell_m: float) -> float | None:
    """The floor at ``xy`` when its own cells are unseen (stepping down a flight: the treads just
    below the edge hide under it): interpolated between the floor ``prev_z`` at ``prev_xy``
    (where the agent stood) and the first seen floor along the move's direction within
    ``AHEAD_M`` beyond ``xy``. None when the agent did not move or sees nothing ahead."""
    step = np.asarray(xy, np.float64) - np.asarray(prev_xy, np.float64)
    d_back = float(np.hypot(*step))
    if d_back < 1e-6:
        return None
    unit = step / d_back
    for d in np.arange(cell_m, AHEAD_M + 1e-9, cell_m):
        r, c = storey.state.to_cell(xy + d * unit, cell_m)
        z = float(storey.elev[r, c])
        if np.isfinite(z):
            return prev_z + (z - prev_z) * d_back / (d_back + d)
    return None


def _cell_floors(cells: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(unique cells (M,), the lowest z in each (M,) float32, whether its points lie within
    ``FLAT_M`` of each other (M,) bool: a floor or a tread, not a wall's foot, whose lowest seen
    point moves with the viewpoint) of points in flat ``cells`` (N,) at heights ``z`` (N,)."""
    u, inv = np.unique(cells, return_inverse=True)
    low = np.full(len(u), np.inf, np.float32)
    high = np.full(len(u), -np.inf, np.float32)
    np.minimum.at(low, inv, z)
    np.maximum.at(high, inv, z)
    return u, low, high - low <= FLAT_M


class StoreyMapBuilder(FusedMapBuilder):
    """``FusedMapBuilder`` on a storey (module docstring): the geometry from the storey's floor
    rasters, the semantics from the points within ``STOREY_BAND_M`` of its floor. Set
    ``storey`` and ``floor_z`` (the agent's floor, metres) before each ``update``."""

    storey: Storey | None = None
    floor_z: float = 0.0
    prev_xy: np.ndarray | None = None   # where the camera was at the last frame (``floor_ahead``)

    def new_voxels(self) -> SemanticVoxelMap:
        """A fresh voxel map (another storey's: the builder's own one is the start storey's)."""
        return SemanticVoxelMap(self.num_classes, self.mapping_cfg, class_names=self.class_names, tsdf=False)

    def update(self, state: MapState, frame, pose: np.ndarray) -> None:
        """Register the frame's height to the storey's floors (``floor_z`` and ``pose`` are
        corrected by the offset found: ``register``), then map it."""
        pose = pose.copy()
        dz = self.register(state, frame.depth, frame.k, pose)
        if dz is None:   # nothing to register on (going down a flight): the floor seen ahead
            ahead = floor_ahead(self.storey, self.prev_xy, pose[:2, 3], self.floor_z, self.cfg.cell_m) \
                if self.prev_xy is not None else None
            dz = 0.0 if ahead is None else float(np.clip(self.floor_z - ahead, -FLOOR_STEP_M, FLOOR_STEP_M))
        pose[2, 3] -= dz
        self.floor_z -= dz
        self._full_depth = frame.depth
        points, _ = pj.backproject(frame.depth, frame.k, pose)
        z = np.full(frame.depth.size, np.nan, np.float32)
        valid = np.flatnonzero(frame.depth.reshape(-1) > 0)
        z[valid] = points[:, 2]
        lo, hi = self.storey.z_ref + STOREY_BAND_M[0], self.storey.z_ref + STOREY_BAND_M[1]
        with np.errstate(invalid="ignore"):
            keep = ((z >= lo) & (z <= hi)).reshape(frame.depth.shape)
        super().update(state, replace(frame, depth=np.where(keep, frame.depth, 0).astype(np.float32)), pose)

    def register(self, state: MapState, depth: np.ndarray, intrinsics: np.ndarray, pose: np.ndarray) -> float | None:
        """The camera's height error, metres: the median, over the cells where this frame sees a
        flat surface below the camera that the storey's map holds too (``Storey.reg``: floors,
        treads, seats, table tops; a wall's foot is not flat), of (height now - height on the
        map); None with fewer than ``REGISTER_MIN_CELLS`` of them (then ``update`` reads the
        floor ahead instead: ``floor_ahead``). Up a flight the treads ahead seem a rise
        lower after each step up: this is how the agent knows it climbed (gps has no height)."""
        cfg, st = self.cfg, self.storey
        points, _ = pj.backproject(depth, intrinsics, pose)
        cells, inside = pj.cell_of(points[:, :2], state.origin, cfg.cell_m, state.size)
        cand = inside & (points[:, 2] <= pose[2, 3] - REGISTER_BELOW_CAMERA_M)
        if not cand.any():
            return None
        u, low, flat = _cell_floors(cells[cand], points[cand, 2])
        with np.errstate(invalid="ignore"):
            # the same cell of another storey (seen through a stair opening) is no match
            diff = low - st.reg.reshape(-1)[u]
            known = flat & (np.abs(diff) <= REGISTER_GATE_M)
        if known.sum() < REGISTER_MIN_CELLS:
            return None
        return float(np.median(diff[known]))

    def project_geometry(self, state: MapState, depth: np.ndarray, intrinsics: np.ndarray, pose: np.ndarray):
        """The storey geometry of the frame's full depth (``update`` hands the band-masked
        depth to the voxel map only); returns the full frame's (pix, cells, inside)."""
        cfg, st, n = self.cfg, self.storey, state.size
        points, pix = pj.backproject(self._full_depth, intrinsics, pose)
        cam_xy, cam_z = pose[:2, 3], pose[2, 3]
        z = points[:, 2]
        cells, inside = pj.cell_of(points[:, :2], state.origin, cfg.cell_m, n)
        elev, top = st.elev.reshape(-1), st.top.reshape(-1)
        cand = inside & (z <= self.floor_z + ELEVATION_REACH_M)
        if cand.any():
            u, low, _ = _cell_floors(cells[cand], z[cand])
            elev[u] = low   # the latest view of a cell's floor
        low_pts = inside & (z <= cam_z - REGISTER_BELOW_CAMERA_M)
        if low_pts.any():   # flat surfaces below the camera: what the next frames register on
            u, low, flat = _cell_floors(cells[low_pts], z[low_pts])
            st.reg.reshape(-1)[u] = np.where(flat, low, np.nan)
        below = inside & (z <= cam_z + cfg.obstacle_above_camera_m)
        np.maximum.at(top, cells[below], z[below])
        base = np.where(np.isfinite(elev[cells]), elev[cells], st.z_ref)
        obst = inside & below & (z - base >= cfg.obstacle_min_height_m)
        flat = state.channels.reshape(NUM_CHANNELS, -1)
        tall = obst & (z >= cam_z - cfg.view_block_below_camera_m)
        flat[MapChannels.VIEW_BLOCK, cells[tall]] = True
        free = pj.free_rays(cam_xy, points, pix, self._full_depth.shape[1], obst, cfg.free_ray_samples)
        fcells, finside = pj.cell_of(free, state.origin, cfg.cell_m, n)
        flat[MapChannels.EXPLORED, fcells[finside]] = True
        flat[MapChannels.EXPLORED, cells[inside]] = True
        state.grow_bbox(np.concatenate([fcells[finside], cells[inside]]))
        self._mark_agent(state, cam_xy)
        r, c = state.to_cell(cam_xy, cfg.cell_m)
        off = pj.disc_offsets(cfg.agent_radius_m / cfg.cell_m) + (r, c)
        off = off[((off >= 0) & (off < n)).all(axis=1)]
        st.stood[off[:, 0], off[:, 1]] = True
        self.recompute_obstacles(state)
        return pix, cells, inside

    def recompute_obstacles(self, state: MapState) -> None:
        """The storey's OBSTACLE channel over its explored window, from its rasters."""
        st, cfg = self.storey, self.cfg
        win = state.window(1)
        e, t = st.elev[win], st.top[win]
        base = np.where(np.isfinite(e), e, st.z_ref)
        obst = t - base >= cfg.obstacle_min_height_m
        with np.errstate(invalid="ignore"):
            for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
                nb = np.full_like(e, np.nan)
                h, w = e.shape
                nb[max(0, -dr):h - max(0, dr), max(0, -dc):w - max(0, dc)] = \
                    e[max(0, dr):h + min(0, dr), max(0, dc):w + min(0, dc)]
                obst |= e - nb > STEP_M
        obst &= ~st.stood[win]
        state.channels[MapChannels.OBSTACLE][win] = obst
