"""The map stage: the agent's semantic maps (``MapState``: the 2D map and, for
``map_type: fused``, the episode's 3D ``SemanticVoxelMap``) and the builders that update them
from each segmented frame, home-robot style, one per ``agent.map_type``
(``agent.registry.MAP_BUILDERS``): ``FusedMapBuilder`` and ``NdfMapBuilder``, on the shared
geometry of ``MapBuilder``. This file owns the map state and the ground projection; fusion
itself is ``mapping``'s (``SemanticVoxelMap.integrate`` with the strategy ``mapping.fusion`` and
its scaling / GLFS parameters / sample weighting from the mapping config), the grid geometry
is ``agent.projection``.

The 2D map is ``n`` x ``n`` cells of ``cfg.cell_m`` centred (within a voxel) on the start
position, in the agent's frame (the episode-start frame, ``agent.sensors``); its cell edges
lie half a voxel away from the voxel centres (``projection.lattice_aligned_origin``) so the
fused projection cannot alias whatever the start pose (``cell_m`` should be a multiple of
``mapping.voxel_size_m``; otherwise cells get unequal numbers of voxel columns). Channels (``MapChannels``) are bool (n, n)
layers; ``MapState.semantic`` (K, n, n) float32 is the confidence that class l is at a cell.

Per frame (``update``), with the segmented frame at the mapping resolution
(``mapping.frame.SegmentedFrame``: depth (h, w) m, logits (h, w, K)), the geometry
(``MapBuilder.project_geometry``: obstacles, explored, holes, the agent's footprint) and then
the semantics, by map type:

- ``fused`` (``FusedMapBuilder``): the frame is fused into the 3D voxel map; the voxels it fused an observation into
  (``SemanticVoxelMap.frame_voxels``: the only ones whose fused value changed) are re-read and
  re-projected: each voxel keeps its
  latest (cell, arg-max class, confidence) in ``agent.votes.VoxelVotes`` and the per-(class, cell) sums and
  counts are updated by difference, so the semantic layer is exactly the mean over all observed
  surface voxels in the cell and the cost per frame does not grow with the house.
- ``ndf`` (``NdfMapBuilder``): per-pixel probabilities softmax(logits / mapping.temperature) (the scalar
  temperature; no 3D map); pixels with confidence >= ``ndf_pixel_threshold`` are projected;
  semantic = max over time of the per-frame per-cell mean.

Obstacles: points with height in [obstacle_min_height_m, camera z + obstacle_above_camera_m]
(max over time) plus collision marks plus floor holes (``HOLE``: pixels with no depth whose ray
meets the floor inside the sensor's range, in cells where no floor point was ever seen; a hole
in a scanned floor returns nothing, and the simulator's navigation mesh has no floor there). Explored: cells of every point plus the free rays of
each image column (``agent.projection.free_rays``) plus the agent's footprint.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Sequence

import numpy as np

from calnav.agent import projection as pj
from calnav.agent.config import AgentConfig
from calnav.agent.segmenters import softmax
from calnav.agent.votes import VoxelVotes
from calnav.common.threads import single_threaded_torch
from calnav.mapping.config import MappingConfig
from calnav.mapping.frame import SegmentedFrame
from calnav.mapping.voxel_map import SemanticVoxelMap


class MapChannels(IntEnum):
    OBSTACLE = 0      # seen obstacle points (height band)
    EXPLORED = 1      # observed cells (points and free rays)
    COLLISION = 2     # cells marked by blocked forward moves
    VISITED = 3       # cells the agent stood on
    HOLE = 4          # floor expected but no depth returned (a hole in a scanned floor), not since seen as floor
    FLOOR = 5         # cells where floor points were seen (clears HOLE for good)
    VIEW_BLOCK = 6    # obstacle points at about the camera's height (walls, tall furniture): they hide what is behind


NUM_CHANNELS = len(MapChannels)


@dataclass
class MapState:
    """Everything the map remembers for one episode. origin (2,) world metres of the map's
    corner; channels (C, n, n) bool; semantic (K, n, n) float32; sums / counts (K, n*n) for the
    fused mean; votes of the fused voxels; voxels: the 3D map (``fused``) or None (``ndf``)."""

    origin: np.ndarray
    channels: np.ndarray
    semantic: np.ndarray
    sums: np.ndarray
    counts: np.ndarray
    votes: VoxelVotes = field(default_factory=VoxelVotes)
    voxels: SemanticVoxelMap | None = None
    bbox: list[int] = field(default_factory=lambda: [1 << 30, -1, 1 << 30, -1])  # explored rows/cols (min, max, min, max)

    @classmethod
    def empty(cls, start_xy: np.ndarray, cfg: AgentConfig, num_classes: int,
              voxels: SemanticVoxelMap | None = None, lattice_m: float | None = None) -> "MapState":
        """An empty map around ``start_xy`` (2,) metres; lattice_m: the voxel size whose
        centres must keep off the cell edges (``projection.lattice_aligned_origin``)."""
        n = cfg.map_cells
        origin = pj.lattice_aligned_origin(start_xy, cfg.map_size_m, lattice_m)
        return cls(origin, np.zeros((NUM_CHANNELS, n, n), bool), np.zeros((num_classes, n, n), np.float32),
                   np.zeros((num_classes, n * n), np.float32), np.zeros((num_classes, n * n), np.int32),
                   voxels=voxels)

    @staticmethod
    def estimate_bytes(cfg: AgentConfig, num_classes: int) -> int:
        """Bytes of ``empty``'s arrays: per cell, NUM_CHANNELS bool layers and K float32
        (semantic), float32 (sums) and int32 (counts) entries."""
        per_cell = NUM_CHANNELS * np.dtype(bool).itemsize + num_classes * (
            np.dtype(np.float32).itemsize * 2 + np.dtype(np.int32).itemsize)
        return cfg.map_cells ** 2 * per_cell

    @property
    def size(self) -> int:
        return self.channels.shape[1]

    def to_cell(self, xy: np.ndarray, cell_m: float) -> tuple[int, int]:
        """(row, col) of world xy (2,) metres (clipped to the map)."""
        c = np.floor((np.asarray(xy, np.float64) - self.origin) / cell_m).astype(int)
        c = np.clip(c, 0, self.size - 1)
        return int(c[1]), int(c[0])

    def to_world(self, row: float, col: float, cell_m: float) -> np.ndarray:
        """World xy (2,) metres of a cell centre."""
        return self.origin + (np.array([col, row], np.float64) + 0.5) * cell_m

    def grow_bbox(self, flat_cells: np.ndarray) -> None:
        """Extend the explored bounding box by flat cell indices (so nothing scans the map)."""
        if len(flat_cells) == 0:
            return
        r, c = np.divmod(flat_cells, self.size)
        b = self.bbox
        self.bbox = [min(b[0], int(r.min())), max(b[1], int(r.max())), min(b[2], int(c.min())), max(b[3], int(c.max()))]

    def window(self, margin_cells: int) -> tuple[slice, slice]:
        """(row slice, col slice) of the explored bounding box plus a margin, clipped."""
        b, n = self.bbox, self.size
        return (slice(max(0, b[0] - margin_cells), min(n, b[1] + margin_cells + 1)),
                slice(max(0, b[2] - margin_cells), min(n, b[3] + margin_cells + 1)))

    def obstacles(self, window: tuple[slice, slice] = (slice(None), slice(None))) -> np.ndarray:
        """Obstacle, collision or floor-hole cells (bool) inside ``window``."""
        ch = self.channels
        return ch[MapChannels.OBSTACLE][window] | ch[MapChannels.COLLISION][window] | ch[MapChannels.HOLE][window]

    def traversable(self, cfg: AgentConfig, window: tuple[slice, slice] = (slice(None), slice(None))) -> np.ndarray:
        """Explored minus obstacles dilated by ``cfg.dilation_cells`` (bool) inside ``window``."""
        return self.channels[MapChannels.EXPLORED][window] & ~pj.dilate(self.obstacles(window), cfg.dilation_cells)


class MapBuilder(ABC):
    """What every map type shares: the map state and one frame's geometry. A map type
    (``agent.registry.MAP_BUILDERS``) adds the voxel map it keeps (``_new_voxels``) and its
    semantics (``update``). class_names: the segmenter's classes (K)."""

    def __init__(self, cfg: AgentConfig, mapping_cfg: MappingConfig, class_names: Sequence[str],
                 depth_range_m: tuple[float, float] = (0.5, 5.0)):
        self.cfg, self.mapping_cfg = cfg, mapping_cfg
        self.depth_range_m = depth_range_m   # the sensor's valid depth (min, max), metres: where holes can show
        self.class_names = tuple(class_names)
        self.num_classes = len(self.class_names)
        self.voxel_size_m = mapping_cfg.voxel_size_m

    def new_state(self, start_xy: np.ndarray) -> MapState:
        """An empty map centred on ``start_xy`` (2,) metres (the agent's frame), with the map
        type's voxel map (``_new_voxels``)."""
        return MapState.empty(start_xy, self.cfg, self.num_classes, self._new_voxels(), lattice_m=self.voxel_size_m)

    def _new_voxels(self) -> SemanticVoxelMap | None:
        """The episode's empty 3D map, or None (a map type without one)."""
        return None

    @abstractmethod
    def update(self, state: MapState, frame: SegmentedFrame, pose: np.ndarray) -> None:
        """Map one frame (its geometry and the map type's semantics); pose (4, 4) world-from-camera."""

    def project_geometry(self, state: MapState, depth: np.ndarray, intrinsics: np.ndarray, pose: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One frame's geometry into ``state``: obstacles, view blockers, explored cells (points
        and free rays), floor holes and the agent's footprint. depth (h, w) m; intrinsics
        (3, 3) at that size; pose (4, 4) world-from-camera. Returns (pix (N,) flat pixel index
        of each back-projected point, cells (N,) its flat map cell, inside (N,) bool: the cell
        is on the map) for the semantics."""
        cfg, n = self.cfg, state.size
        points, pix = pj.backproject(depth, intrinsics, pose)
        cam_xy = pose[:2, 3]
        obst = pj.obstacle_points(points, cfg.obstacle_min_height_m, pose[2, 3] + cfg.obstacle_above_camera_m)
        cells, inside = pj.cell_of(points[:, :2], state.origin, cfg.cell_m, n)
        flat_channels = state.channels.reshape(NUM_CHANNELS, -1)
        flat_channels[MapChannels.OBSTACLE, cells[inside & obst]] = True
        tall = inside & obst & (points[:, 2] >= pose[2, 3] - cfg.view_block_below_camera_m)
        flat_channels[MapChannels.VIEW_BLOCK, cells[tall]] = True
        free = pj.free_rays(cam_xy, points, pix, depth.shape[1], obst, cfg.free_ray_samples)
        fcells, finside = pj.cell_of(free, state.origin, cfg.cell_m, n)
        flat_channels[MapChannels.EXPLORED, fcells[finside]] = True
        flat_channels[MapChannels.EXPLORED, cells[inside]] = True
        state.grow_bbox(np.concatenate([fcells[finside], cells[inside]]))
        if cfg.hole_margin_m > 0:
            self._mark_holes(state, depth, intrinsics, pose, points, pix, cells, inside)
        self._mark_agent(state, cam_xy)
        return pix, cells, inside

    def _mark_holes(self, state: MapState, depth: np.ndarray, intrinsics: np.ndarray, pose: np.ndarray,
                    points: np.ndarray, pix: np.ndarray, cells: np.ndarray, inside: np.ndarray) -> None:
        """Floor seen (points within floor_tolerance_m of z = 0) clears a cell for good; floor
        expected but no depth returned (``projection.floor_holes``: at least hole_margin_m inside
        the sensor's range, with floor seen below it in the image) marks a hole there, unless
        its floor was seen."""
        cfg, n = self.cfg, state.size
        flat = state.channels.reshape(NUM_CHANNELS, -1)
        floor = inside & (np.abs(points[:, 2]) <= cfg.floor_tolerance_m)
        flat[MapChannels.FLOOR, cells[floor]] = True
        flat[MapChannels.HOLE, cells[floor]] = False
        near, far = self.depth_range_m
        floor_pixels = np.zeros(depth.size, bool)
        floor_pixels[pix[floor]] = True
        holes = pj.floor_holes(depth, intrinsics, pose, near + cfg.hole_margin_m, far - cfg.hole_margin_m,
                               floor_pixels.reshape(depth.shape))
        hcells, hinside = pj.cell_of(holes, state.origin, cfg.cell_m, n)
        hcells = hcells[hinside]
        hcells = hcells[~flat[MapChannels.FLOOR, hcells]]
        flat[MapChannels.HOLE, hcells] = True
        flat[MapChannels.EXPLORED, hcells] = True

    def _mark_agent(self, state: MapState, xy: np.ndarray) -> None:
        """Footprint explored and free, centre visited."""
        cfg = self.cfg
        r, c = state.to_cell(xy, cfg.cell_m)
        off = pj.disc_offsets(cfg.agent_radius_m / cfg.cell_m) + (r, c)
        off = off[((off >= 0) & (off < state.size)).all(axis=1)]
        state.channels[MapChannels.EXPLORED][off[:, 0], off[:, 1]] = True
        state.channels[MapChannels.OBSTACLE][off[:, 0], off[:, 1]] = False
        state.channels[MapChannels.VIEW_BLOCK][off[:, 0], off[:, 1]] = False
        state.channels[MapChannels.HOLE][off[:, 0], off[:, 1]] = False   # it stands there: floor
        state.channels[MapChannels.VISITED][r, c] = True
        state.grow_bbox(off[:, 0] * state.size + off[:, 1])


class FusedMapBuilder(MapBuilder):
    """``map_type: fused``: the frame fused into the episode's 3D voxel map, whose changed
    voxels are re-projected to the 2D map (module docstring)."""

    def __init__(self, cfg: AgentConfig, mapping_cfg: MappingConfig, class_names: Sequence[str],
                 depth_range_m: tuple[float, float] = (0.5, 5.0)):
        super().__init__(cfg, mapping_cfg, class_names, depth_range_m)
        self._voxels: SemanticVoxelMap | None = None   # the one voxel map, emptied for each episode

    def _new_voxels(self) -> SemanticVoxelMap:
        """The builder keeps one voxel map and empties it for each episode
        (``SemanticVoxelMap.reset``: the grown allocation is kept, so later episodes skip
        Open3D's ~1 s hashmap doublings), so the previous state's ``voxels`` are emptied too.
        It fuses semantics without the TSDF (``SemanticVoxelMap`` ``tsdf=False``): the
        projection reads only the semantics of the voxels a frame fused into, so the agent's
        actions are the same either way (a Rerun recording shows ``observed_voxels``)."""
        if self._voxels is None:
            self._voxels = SemanticVoxelMap(self.num_classes, self.mapping_cfg, class_names=self.class_names,
                                            tsdf=False)
        return self._voxels.reset()

    def update(self, state: MapState, frame: SegmentedFrame, pose: np.ndarray) -> None:
        """Fuse the frame into ``state.voxels``, then project; pose (4, 4) world-from-camera."""
        state.voxels.integrate(frame.depth, frame.k, pose, logits=frame.logits, rgb=frame.rgb)
        self.project_geometry(state, frame.depth, frame.k, pose)
        self._project_fused(state, state.voxels)

    def _project_fused(self, state: MapState, vmap) -> None:
        """Re-project the voxels this frame fused an observation into (``vmap.frame_voxels``: the
        voxels whose fused values changed), in key order as the votes need."""
        ijk, flat = vmap.frame_voxels
        keys = VoxelVotes.encode(ijk)
        order = np.argsort(keys)   # unique keys: one observation per voxel and frame
        keys, ijk, flat = keys[order], ijk[order], flat[order]
        with single_threaded_torch():   # small tensors: extra torch threads only contend
            probs = vmap.fused_probs(flat)
        cls = probs.argmax(axis=1)
        state.votes.vote(keys, ijk, cls, probs[np.arange(len(cls)), cls], self.voxel_size_m, state.origin,
                         self.cfg.cell_m, state.sums, state.counts, state.semantic)


class NdfMapBuilder(MapBuilder):
    """``map_type: ndf``: no 3D map; each frame's thresholded pixel probabilities projected to
    the 2D map, max over time (module docstring)."""

    def update(self, state: MapState, frame: SegmentedFrame, pose: np.ndarray) -> None:
        """Project the frame's probabilities softmax(logits / mapping.temperature); pose (4, 4)
        world-from-camera."""
        probs = softmax(frame.logits, self.mapping_cfg.temperature)
        pix, cells, inside = self.project_geometry(state, frame.depth, frame.k, pose)
        self._project_ndf(state, probs.reshape(-1, probs.shape[-1])[pix], cells, inside)

    def _project_ndf(self, state: MapState, probs: np.ndarray, cells: np.ndarray, inside: np.ndarray) -> None:
        """SemExp-style: thresholded detections, per-frame cell mean, max over time."""
        cls = probs.argmax(axis=1)
        conf = probs[np.arange(len(cls)), cls]
        keep = inside & (conf >= self.cfg.ndf_pixel_threshold)
        ncell = state.size ** 2
        u, sums, counts = pj.sparse_bin_sums(cls[keep].astype(np.int64) * ncell + cells[keep], conf[keep])
        sem = state.semantic.reshape(-1)
        sem[u] = np.maximum(sem[u], sums / counts)
