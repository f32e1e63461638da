"""The agent's map as a library user reads and saves it (``agent.navigator.Navigator.map`` /
``save_map``): ``AgentMap``, a copy of the explored part of the 2D semantic map and the 3D
voxel map, in the episode-start frame.

Frame and axes: origin at the camera's position at the episode's first step, on the floor; +x
forward at that step, +y to its left, +z up; metres (``envs.task``'s start frame, the frame of
Habitat's gps / compass). The 2D map's cell (row, col) covers x in [origin[0] + col * cell_m,
+ cell_m) and y in [origin[1] + row * cell_m, + cell_m): rows grow along +y, columns along +x.

The file (``save`` / ``load``, a versioned ``.npz``, ``common.npz``) is a ``calnav map`` map file
(format ``MAP_FORMAT_VERSION``: ``centres`` (N, 3) float32 voxel centres in metres, ``probs``
(N, K) float32 fused probabilities, ``class_names`` and ``voxel_size_m`` in its metadata, which
``calnav view`` opens) with the 2D map added: ``semantic`` (K, h, w) float32, ``channels``
(C, h, w) bool, ``origin`` (2,) float64, and ``cell_m``, ``channel_names``, ``goal``,
``steps``, ``map_type`` in the metadata.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calnav.agent.semantic_map import MapChannels, MapState

# The format of ``calnav map``'s map.npz (``eval.sequence.map_cmd.MAP_FORMAT_VERSION``, which
# agent/ cannot import; a test checks they agree): the agent's file is one of those maps.
MAP_FORMAT_VERSION = 1
CHANNEL_NAMES: tuple[str, ...] = tuple(c.name.lower() for c in MapChannels)   # the 2D map's channels, in order


@dataclass(frozen=True)
class AgentMap:
    """A copy of the agent's maps (module docstring for the frame). origin (2,) float64 metres:
    the corner of cell (0, 0); cell_m metres; channels (C, h, w) bool named ``channel_names``
    (obstacle, explored, collision, visited, hole, floor, view_block: ``agent.semantic_map``);
    semantic (K, h, w) float32: the confidence that class k is at a cell, K = ``class_names``;
    voxel_centres (N, 3) float32 metres and voxel_probs (N, K) float32: every voxel of the 3D map
    with a semantic observation (``agent.map_type: fused``; N = 0 for ``ndf``, which keeps no
    3D map), voxel_size_m metres; goal: the goal category searched; steps: the agent's steps."""

    origin: np.ndarray
    cell_m: float
    channels: np.ndarray
    semantic: np.ndarray
    class_names: tuple[str, ...]
    voxel_centres: np.ndarray
    voxel_probs: np.ndarray
    voxel_size_m: float
    goal: str = ""
    steps: int = 0
    map_type: str = ""
    channel_names: tuple[str, ...] = CHANNEL_NAMES

    @classmethod
    def of_state(cls, state: MapState, cell_m: float, class_names, voxel_size_m: float, goal: str, steps: int,
                 map_type: str) -> "AgentMap":
        """The explored bounding box of ``state`` (copied: the agent goes on changing its own)."""
        rows, cols = state.window(0)
        origin = state.origin + np.array([cols.start, rows.start], np.float64) * cell_m
        if state.voxels is not None:   # the agent's voxel map keeps no TSDF surface: every observed voxel
            centres, probs = state.voxels.observed_voxels()
        else:
            centres, probs = np.zeros((0, 3), np.float32), np.zeros((0, len(class_names)), np.float32)
        return cls(origin, float(cell_m), state.channels[:, rows, cols].copy(), state.semantic[:, rows, cols].copy(),
                   tuple(class_names), np.asarray(centres, np.float32), np.asarray(probs, np.float32),
                   float(voxel_size_m), goal, int(steps), map_type)

    def layer(self, name: str) -> np.ndarray:
        """The (h, w) bool channel ``name`` (one of ``channel_names``)."""
        if name not in self.channel_names:
            raise ValueError(f"unknown map channel {name!r}; valid: {', '.join(self.channel_names)}")
        return self.channels[self.channel_names.index(name)]

    def confidence(self, class_name: str) -> np.ndarray:
        """The (h, w) float32 confidence layer of ``class_name`` (one of ``class_names``)."""
        if class_name not in self.class_names:
            raise ValueError(f"unknown class {class_name!r}; valid: {', '.join(self.class_names)}")
        return self.semantic[self.class_names.index(class_name)]

    def point(self, row: float, col: float) -> tuple[float, float]:
        """(x, y) metres of the centre of cell (row, col)."""
        x, y = self.origin + (np.array([col, row], np.float64) + 0.5) * self.cell_m
        return float(x), float(y)

    def cell(self, x: float, y: float) -> tuple[int, int]:
        """(row, col) of the cell holding (x, y) metres (it may lie outside the arrays)."""
        col, row = np.floor((np.array([x, y], np.float64) - self.origin) / self.cell_m).astype(int)
        return int(row), int(col)

    def save(self, path: str | Path) -> Path:
        """Write the map to ``path`` (a versioned ``.npz``, atomically); returns the path."""
        from calnav.common.npz import save_versioned_npz

        arrays = {"centres": self.voxel_centres, "probs": self.voxel_probs, "semantic": self.semantic,
                  "channels": self.channels, "origin": self.origin}
        meta = {"class_names": list(self.class_names), "voxel_size_m": self.voxel_size_m, "cell_m": self.cell_m,
                "channel_names": list(self.channel_names), "goal": self.goal, "steps": self.steps,
                "map_type": self.map_type,
                "frame": "episode start: x forward, y left, z up from the floor, metres; rows along +y, cols along +x"}
        return save_versioned_npz(path, arrays, meta, MAP_FORMAT_VERSION)

    @classmethod
    def load(cls, path: str | Path) -> "AgentMap":
        """A map written by ``save``; ValueError naming the file when it is not one."""
        from calnav.common.npz import load_versioned_npz

        arrays, meta = load_versioned_npz(path, MAP_FORMAT_VERSION, "agent map file")
        missing = [k for k in ("centres", "probs", "semantic", "channels", "origin") if k not in arrays]
        if missing:
            raise ValueError(f"{path} is not an agent map (no {', '.join(missing)}): a calnav map file without the "
                             "agent's 2D map")
        return cls(arrays["origin"], float(meta["cell_m"]), arrays["channels"], arrays["semantic"],
                   tuple(meta["class_names"]), arrays["centres"], arrays["probs"], float(meta["voxel_size_m"]),
                   str(meta.get("goal", "")), int(meta.get("steps", 0)), str(meta.get("map_type", "")),
                   tuple(meta["channel_names"]))
