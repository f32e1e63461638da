"""`calnav view-episode`: a top-down map of an episode (navigable area, objects by class,
start, goal instances, view points, the path an agent took) and an RGB / depth / semantic
strip of frames along that path."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from dataclasses import dataclass
from calnav.eval.arguments import Command, arg

N_STRIP_FRAMES = 4
TOP_VIEW_CUT_M = 2.0  # the floor plan shows surfaces below this height (no ceilings), metres


def top_down_class_map(scene, navgrid) -> np.ndarray:
    """(H, W) int class id of the highest surface below ``TOP_VIEW_CUT_M`` in each nav cell
    (-1 where there is none): a floor plan with walls, furniture and floors, no ceiling."""
    from calnav.envs.scene import sample_surface

    keep = scene.tri_class >= 0
    if "ceiling" in scene.class_names:
        keep &= scene.tri_class != scene.class_names.index("ceiling")
    tris = scene.vertices[scene.triangles[keep]]
    # ~16 samples per cell, so no cell of a large floor triangle is left without one
    pts, tri_index = sample_surface(tris, navgrid.cell_m / 4, np.random.default_rng(0), return_index=True)
    cls = scene.tri_class[keep][tri_index]
    below = pts[:, 2] < scene.floor_z + TOP_VIEW_CUT_M
    pts, cls = pts[below], cls[below]
    rc = navgrid.to_cell(pts[:, :2])
    h, w = navgrid.navigable.shape
    inside = navgrid.in_grid(rc)
    rc, z, cls = rc[inside], pts[inside, 2], cls[inside]
    order = np.argsort(-z, kind="stable")  # highest first; np.unique keeps each cell's first
    flat = rc[order, 0] * w + rc[order, 1]
    _, first = np.unique(flat, return_index=True)
    out = np.full(h * w, -1, dtype=np.int64)
    out[flat[first]] = cls[order][first]
    return out.reshape(h, w)


def draw_episode(env, path_xy: np.ndarray, frames: list[dict], out_dir: Path) -> tuple[Path, Path]:
    """Write ``topdown.png`` and ``frames.png`` into ``out_dir``; returns both paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from calnav.envs.semantics import CLASS_NAMES, colorize

    from calnav.envs.config import require_single_storey

    e = env.unwrapped
    require_single_storey(e.config, "calnav view-episode's top-down map")
    nav, ep = e.navgrid, e.episode
    out_dir.mkdir(parents=True, exist_ok=True)
    cls = top_down_class_map(e.scene, nav)
    img = colorize(cls).astype(np.float32) / 255
    img[nav.navigable] = 0.55 * img[nav.navigable] + 0.45 * np.array([1.0, 1.0, 1.0])
    h, w = nav.navigable.shape
    x0, y0 = nav.origin_xy
    extent = (x0, x0 + w * nav.cell_m, y0, y0 + h * nav.cell_m)
    fig, ax = plt.subplots(figsize=(9, 9 * h / max(w, 1) + 0.8))
    ax.imshow(img, origin="lower", extent=extent, interpolation="nearest")
    for g in ep.goals:
        ax.scatter(g.view_points[:, 0], g.view_points[:, 1], s=2, c="gold", alpha=0.5, linewidths=0)
        ax.scatter([g.position[0]], [g.position[1]], marker="*", s=220, c="red", edgecolors="k")
    ax.plot(path_xy[:, 0], path_xy[:, 1], "-", c="royalblue", lw=2, label="path")
    sx, sy = ep.start_position
    ax.scatter([sx], [sy], s=90, c="lime", edgecolors="k", zorder=5, label="start")
    ax.arrow(sx, sy, 0.5 * math.cos(ep.start_yaw), 0.5 * math.sin(ep.start_yaw), width=0.05, color="k")
    present = sorted({int(c) for c in np.unique(cls) if c >= 0})
    handles = [plt.Line2D([], [], ls="", marker="s", color=np.array(colorize(np.array([[c]]))[0, 0]) / 255,
                          label=CLASS_NAMES[c]) for c in present]
    handles += [plt.Line2D([], [], ls="", marker="*", color="red", label=f"goal: {ep.object_category}"),
                plt.Line2D([], [], ls="", marker=".", color="gold", label="view points")]
    ax.legend(handles=handles + ax.get_legend_handles_labels()[0], loc="upper left",
              bbox_to_anchor=(1.01, 1), fontsize=8)
    ax.set_title(f"{ep.episode_id}: find {ep.object_category} (geodesic {ep.geodesic_distance:.1f} m)")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    top = out_dir / "topdown.png"
    fig.savefig(top, dpi=110, bbox_inches="tight")
    plt.close(fig)

    picks = np.linspace(0, len(frames) - 1, min(N_STRIP_FRAMES, len(frames))).astype(int)
    fig, axes = plt.subplots(3, len(picks), figsize=(3.2 * len(picks), 7.5), squeeze=False)
    for j, k in enumerate(picks):
        o = frames[k]
        axes[0, j].imshow(o["rgb"])
        axes[0, j].set_title(f"step {k}")
        axes[1, j].imshow(o["depth"][..., 0], cmap="viridis", vmin=0, vmax=1.0 if e.config.normalize_depth else e.config.max_depth_m)
        axes[2, j].imshow(colorize(o["semantic"]) if "semantic" in o else np.zeros_like(o["rgb"]))
        for a in axes[:, j]:
            a.axis("off")
    strip = out_dir / "frames.png"
    fig.savefig(strip, dpi=90, bbox_inches="tight")
    plt.close(fig)
    return top, strip


def view_episode_configs(args) -> list:
    """The config ``calnav view-episode`` runs: its ``run.agent`` is the agent drawn (``--agent``,
    else a ``run.agent`` override, else the oracle: the shorthand's default), so the preflight
    checks that agent."""
    from calnav.eval.shorthands import load_command_config

    return [load_command_config(args)]


def main_view_episode(args, configs) -> None:
    """``configs``: ``view_episode_configs(args)``, checked by the preflight."""
    import gymnasium as gym

    import calnav.envs  # noqa: F401
    from calnav.agent.navigator import EpisodeAgent, Navigator
    from calnav.eval.config import agent_setup
    from calnav.eval.objectnav.hooks import PathHook
    from calnav.eval.results_dir import check_output_dir
    from calnav.eval.rollout import rollout

    from calnav.envs.episodes import check_split_capacity

    cfg = configs[0]
    check_output_dir(args.output)
    if args.episode >= 0 and not cfg.env.dataset.data_path:   # past the split's most episodes: refused before its houses are generated
        check_split_capacity(str(args.episode + 1), cfg.env.split, cfg.env)
    env = gym.make("calnav/ObjectNav-v0", split=cfg.env.split, config=cfg.env)
    n = len(env.unwrapped.episodes)
    if not 0 <= args.episode < n:
        raise ValueError(f"--episode {args.episode} is outside the split, which has episodes 0:{n}")
    agent = EpisodeAgent(Navigator(agent_setup(cfg), simulator=env.unwrapped.simulator_handle()))
    track = PathHook()
    info = rollout(env, agent, args.episode, [track]).info
    top, strip = draw_episode(env, track.path, track.frames, Path(args.output))
    print(f"episode {info['episode_id']}: success {info['success']:.0f}, spl {info['spl']:.3f}, "
          f"steps {info['steps']}")
    print(f"wrote {top} and {strip}")


@dataclass
class ViewEpisodeArgs:
    """``calnav view-episode``'s flags."""

    # its range is the split's episodes: main_view_episode checks it against the split
    episode: int = arg(0, "episode index within the split")
    agent: str | None = arg(None, "agent whose path is drawn: oracle (default; the shortest path) or peanut; "
                                  "shorthand for run.agent=NAME", metavar="NAME", sets="run.agent",
                            sets_default="oracle")
    output: str = arg("runs/view", "output directory")


COMMAND = Command(ViewEpisodeArgs, main_view_episode, view_episode_configs, config="configs/objectnav.yaml")
