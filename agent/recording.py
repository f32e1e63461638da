"""An episode of the PEANUT-like agent as a Rerun recording (``calnav objectnav --rerun N``;
needs the ``[viz]`` extra). Read-only on the agent, like ``agent.visualize``: the actions, hence
the metrics, are the same with or without a recording.

Timeline ``step`` (the agent's step count, 1 = the first observation). Entities (``world`` is
the agent's map frame: the episode-start frame, z up, metres):

| entity | what | when |
|---|---|---|
| ``world/camera`` | the camera's pose (OpenCV axes; the pinhole is static) | every step |
| ``world/camera/rgb`` / ``depth`` / ``segmentation`` | the frame the agent mapped (its mapping resolution; RGB as JPEG, depth in mm, uint16) and its arg-max classes | every step |
| ``world/trajectory`` | the camera positions so far | every ``map_every`` steps and the last |
| ``world/map/class`` / ``world/map/confidence`` | the fused 3D map's observed voxels (every voxel with a semantic observation) by class / by arg-max probability (``common.rerun_io.log_voxels``; ``map_type: fused`` only) | every ``map_every`` steps and the last |
| ``map2d/topdown`` | the video panel's top-down map (explored, obstacles, collisions, holes, frontiers, goal confidence, detected component, path, long- and short-term goal) | every ``map_every`` steps and the last |
| ``map2d/obstacles`` / ``explored`` / ``frontiers`` / ``detection`` | the 2D channels (0 / 255 images of the explored window plus a margin, +y up) | every ``map_every`` steps and the last |
| ``map2d/goal_confidence`` | the goal class's confidence layer (float32 in [0, 1]) | every ``map_every`` steps and the last |
| ``map2d/goals`` | long-term (``ltg``) and short-term (``stg``) goal as labelled points | every ``map_every`` steps and the last |
| ``metrics/action`` / ``distance_to_goal`` / ``success`` | the action id, the running DTG (m) and Success | every step |
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from calnav.agent.semantic_map import MapChannels
from calnav.agent.step import Step
from calnav.agent.visualize import MAP_MARGIN_CELLS, class_palette, topdown
from calnav.common import rerun_io

DEFAULT_MAP_EVERY = 50   # steps between 3D / 2D map snapshots (a full map read-out each: ~40 ms at 160x120)
JPEG_QUALITY = 90        # the RGB frames are logged JPEG-compressed (a tenth of the raw bytes)
DEPTH_MM = 1000.0        # depth is logged as uint16 millimetres (half the bytes of float32)


class EpisodeRecording:
    """``EpisodeRecording(path, class_names, episode_id, map_every)`` (``class_names``: the
    agent's map classes, K); ``step(step, action, info)`` with the agent's ``agent.step.Step``
    after each env step (``info``: the env's, with ``distance_to_goal`` and ``success``);
    ``close()`` writes the last map snapshot and flushes the file."""

    def __init__(self, path: str | Path, class_names: tuple[str, ...], episode_id: str,
                 map_every: int = DEFAULT_MAP_EVERY):
        if map_every < 1:
            raise ValueError(f"map_every must be >= 1 steps, got {map_every}")
        self.rr = rerun_io.require_rerun()
        self.path, self.map_every = Path(path), int(map_every)
        self.palette = class_palette(len(class_names))
        self.rec = rerun_io.new_recording(f"calnav objectnav {episode_id}", self.path, tuple(class_names),
                                          self.palette)
        self.positions: list[np.ndarray] = []
        self.last_step = 0
        self.last: Step | None = None   # the last step logged: the closing map snapshot's
        # per-step numbers are buffered and sent as columns at each map snapshot and at the end
        # (one call instead of four per step: logging them one by one cost ~0.4 ms a step)
        self._columns: dict[str, list] = {k: [] for k in ("step", "rotation", "action", "distance_to_goal", "success")}

    def step(self, step: Step, action: int, info: dict) -> None:
        """Log the step the agent just took (its frame, pose, ``action``) and the env's ``info``."""
        rr, rec, frame = self.rr, self.rec, step.frame
        self.last = step
        rec.set_time("step", sequence=step.steps)
        pose = step.pose
        h, w = frame.depth.shape
        if not self.positions:   # the first step: the camera's pinhole is fixed, logged once
            rec.log("world/camera", rr.Pinhole(image_from_camera=frame.k, width=w, height=h,
                                               camera_xyz=rr.ViewCoordinates.RDF), static=True)
        rec.log("world/camera/rgb", rerun_io.jpeg_image(frame.rgb, JPEG_QUALITY))
        rec.log("world/camera/depth", rr.DepthImage(np.round(frame.depth * DEPTH_MM).astype(np.uint16), meter=DEPTH_MM))
        label_type = np.uint8 if len(step.class_names) <= 256 else np.uint16
        rec.log("world/camera/segmentation", rr.SegmentationImage(frame.labels.astype(label_type)))
        cols = self._columns
        cols["step"].append(step.steps)
        cols["rotation"].append(pose[:3, :3].copy())
        cols["action"].append(float(action))
        cols["distance_to_goal"].append(float(info.get("distance_to_goal", np.nan)))
        cols["success"].append(float(info.get("success", 0.0)))
        self.positions.append(pose[:3, 3].astype(np.float32))
        self.last_step = step.steps
        if step.steps % self.map_every == 0:
            self._maps(step)

    def _send_columns(self) -> None:
        """The buffered per-step numbers: camera pose, action, DTG, Success."""
        rr, rec, cols = self.rr, self.rec, self._columns
        n = len(cols["step"])
        if n == 0:
            return
        index = [rr.TimeColumn("step", sequence=cols["step"])]
        rec.send_columns("world/camera", index, rr.Transform3D.columns(
            translation=np.stack(self.positions[-n:]), mat3x3=np.stack(cols["rotation"])))
        for name in ("action", "distance_to_goal", "success"):
            rec.send_columns(f"metrics/{name}", index, rr.Scalars.columns(scalars=np.asarray(cols[name])))
        for v in cols.values():
            v.clear()

    def _maps(self, step: Step) -> None:
        """The 3D and 2D map snapshots at ``step``."""
        rr, rec, st = self.rr, self.rec, step.state
        self._send_columns()
        rec.log("world/trajectory", rr.LineStrips3D([np.stack(self.positions)], colors=[(255, 0, 0)]))
        if st.voxels is not None:
            coords, probs = st.voxels.observed_voxels()   # the agent's map keeps no TSDF surface
            rerun_io.log_voxels(rec, "world/map", coords, probs, st.voxels.cfg.voxel_size_m, self.palette)
        rec.log("map2d/topdown", rr.Image(topdown(step)))
        win, ch = st.window(MAP_MARGIN_CELLS), st.channels   # the explored box + the video panel's margin
        explored = ch[MapChannels.EXPLORED]
        layers = {"obstacles": st.obstacles(), "explored": explored,
                  "frontiers": np.zeros_like(explored), "detection": np.zeros_like(explored)}
        info = step.info
        if info is not None and info.frontiers is not None:
            layers["frontiers"] = info.frontiers
        if info is not None and info.detection is not None and info.detection.found and info.window is not None:
            layers["detection"][info.window] = info.detection.mask
        for name, layer in layers.items():
            rec.log(f"map2d/{name}", rr.Image(layer[win][::-1].astype(np.uint8) * 255))
        rec.log("map2d/goal_confidence", rr.Image(st.semantic[step.goal_channel][win][::-1].astype(np.float32)))
        points, labels = [], []
        # the step's goals are in window coordinates (``StepInfo``): to map cells, then to the crop
        off = np.array([info.window[0].start, info.window[1].start]) if info is not None and info.window else np.zeros(2)
        for label, rc in (("ltg", info.long_term_goal if info else None),
                          ("stg", info.plan.short_term_goal if info is not None and info.plan is not None else None)):
            if rc is not None:
                r, c = off + rc
                points.append((c - win[1].start, win[0].stop - 1 - r))   # (x, y) in the flipped crop
                labels.append(label)
        rec.log("map2d/goals", rr.Points2D(np.array(points, np.float32).reshape(-1, 2), labels=labels,
                                          colors=[(255, 190, 0) if lb == "ltg" else (255, 0, 0) for lb in labels]))

    def close(self) -> Path:
        """The last step's map snapshot (unless just logged), then flush; returns the path."""
        if self.positions and self.last_step % self.map_every != 0:
            self._maps(self.last)
        self._send_columns()
        self.rec.flush()
        self.rec.disconnect()
        return self.path
