"""Per-step visualisation: the RGB frame, the segmentation and a top-down map panel
(explored, obstacles, collision marks, frontiers, goal-class confidence, detected goal
component, long-term goal, short-term goal, path), and an episode video writer.

``render_panel(agent) -> (H, W, 3) uint8`` reads the agent's last frame, map state and step
info; ``EpisodeVideo(path)`` appends panels and writes mp4 (imageio-ffmpeg) or gif.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from calnav.agent.semantic_map import MapChannels
from calnav.agent.step import Step

PANEL_HEIGHT = 360          # output panel height, pixels
MAP_MARGIN_CELLS = 20       # top-down crop margin around the explored area, cells
COLORS = {                  # RGB
    "unknown": (255, 255, 255), "explored": (225, 225, 225), "obstacle": (90, 90, 90),
    "collision": (200, 60, 200), "hole": (40, 40, 140), "frontier": (60, 120, 255), "goal": (0, 200, 0),
    "ltg": (255, 190, 0), "stg": (255, 0, 0), "path": (0, 150, 150), "agent": (255, 0, 0),
}
VIDEO_FPS = 6               # frames per second of episode videos


def topdown(step: Step) -> np.ndarray:
    """(h, w, 3) uint8 top-down view of a step's map (``agent.step.Step``), cropped to the
    explored area, +y up."""
    st, ch = step.state, step.state.channels
    img = np.empty(ch.shape[1:] + (3,), np.uint8)
    img[:] = COLORS["unknown"]
    img[ch[MapChannels.EXPLORED]] = COLORS["explored"]
    conf = st.semantic[step.goal_channel]
    shade = conf > 0
    red = np.array([255, 0, 0], np.float32)
    img[shade] = (img[shade] * (1 - conf[shade, None]) + red * conf[shade, None]).astype(np.uint8)
    img[ch[MapChannels.OBSTACLE]] = COLORS["obstacle"]
    img[ch[MapChannels.COLLISION]] = COLORS["collision"]
    img[ch[MapChannels.HOLE]] = COLORS["hole"]
    info = step.info
    win = info.window if info is not None and info.window is not None else (slice(0, None), slice(0, None))
    off = np.array([win[0].start, win[1].start])
    if info is not None and info.frontiers is not None:
        img[info.frontiers] = COLORS["frontier"]
    if info is not None and info.detection is not None and info.detection.found:
        img[win][info.detection.mask] = COLORS["goal"]
    for r, c in step.path:
        img[r, c] = COLORS["path"]
    if info is not None and info.long_term_goal is not None:
        cv2.circle(img, tuple(int(v) for v in (off + info.long_term_goal)[::-1]), 3, COLORS["ltg"], -1)
    if info is not None and info.plan is not None and info.plan.short_term_goal is not None:
        cv2.circle(img, tuple(int(v) for v in (off + info.plan.short_term_goal)[::-1]), 2, COLORS["stg"], -1)
    if step.path:
        cv2.circle(img, step.path[-1][::-1], 3, COLORS["agent"], 1)
    rows, cols = np.nonzero(ch[MapChannels.EXPLORED])
    if len(rows):
        m = MAP_MARGIN_CELLS
        img = img[max(0, rows.min() - m):rows.max() + m + 1, max(0, cols.min() - m):cols.max() + m + 1]
    return img[::-1].copy()   # row 0 at the bottom: +y up


def _fit(img: np.ndarray, height: int) -> np.ndarray:
    h, w = img.shape[:2]
    return cv2.resize(img, (max(1, round(w * height / h)), height), interpolation=cv2.INTER_NEAREST)


def class_palette(num_classes: int) -> np.ndarray:
    """(K, 3) uint8: a fixed, distinguishable colour per class id of the agent's segmenter
    (matplotlib's tab20, cycled beyond 20 classes)."""
    from matplotlib import colormaps

    colours = colormaps["tab20"](np.arange(num_classes) % 20)[:, :3]
    return np.round(colours * 255).astype(np.uint8)


def render_panel(step: Step) -> np.ndarray:
    """RGB | segmentation | top-down map of an agent's step (``agent.step.Step``), side by
    side, (PANEL_HEIGHT, W, 3) uint8."""
    frame = step.frame
    palette = class_palette(len(step.class_names))
    seg = palette[np.clip(frame.labels, 0, len(palette) - 1)]
    parts = [_fit(frame.rgb, PANEL_HEIGHT), _fit(seg, PANEL_HEIGHT), _fit(topdown(step), PANEL_HEIGHT)]
    panel = np.concatenate(parts, axis=1)
    mode = step.info.mode if step.info is not None else ""
    cv2.putText(panel, f"step {step.steps} {step.goal_name} {mode}", (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6,
                (255, 255, 0), 2)
    return panel


class EpisodeVideo:
    """Collect panels and write them as an mp4 (``.mp4``, imageio-ffmpeg) or gif."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.frames: list[np.ndarray] = []

    def add(self, panel: np.ndarray) -> None:
        if self.frames and panel.shape != self.frames[0].shape:  # the map crop grows: pad/crop to the first size
            h, w = self.frames[0].shape[:2]
            canvas = np.zeros_like(self.frames[0])
            canvas[:min(h, panel.shape[0]), :min(w, panel.shape[1])] = panel[:h, :w]
            panel = canvas
        self.frames.append(panel)

    def write(self) -> Path:
        import imageio.v2 as imageio

        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.suffix == ".mp4":
            h, w = self.frames[0].shape[:2]
            frames = [f[:h - h % 2, :w - w % 2] for f in self.frames]  # even sizes for yuv420p
            imageio.mimwrite(self.path, frames, fps=VIDEO_FPS, macro_block_size=1)
        else:
            imageio.mimwrite(self.path, self.frames, duration=1.0 / VIDEO_FPS)
        return self.path
