"""The pictures of ``calnav check-scene``: a top-down PNG of one scene's navmesh and a Rerun
recording of the mesh with it. ``r`` is a row of ``eval.scanning.check.check_one`` (scene,
mesh, passages, episodes)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from calnav.envs.semantics import GOAL_CATEGORIES, PALETTE

ISLAND_COLOURS = np.array([[60, 170, 75], [70, 130, 220], [180, 90, 200], [0, 160, 160], [200, 160, 40]], np.uint8)
GROUND_RGB, BLOCKED_RGB, DROPPED_RGB = (215, 215, 210), (45, 45, 50), (240, 150, 60)


def navmesh_image(mesh) -> np.ndarray:
    """(H, W, 3) uint8 picture, row 0 = lowest y: not walkable dark, walkable ground light, kept
    islands coloured (the largest green), eroded pieces too small to keep orange."""
    img = np.empty(mesh.ground.shape + (3,), np.uint8)
    img[:] = BLOCKED_RGB
    img[mesh.ground] = GROUND_RGB
    img[(mesh.eroded > 0) & (mesh.islands < 0)] = DROPPED_RGB
    nav = mesh.islands >= 0
    img[nav] = ISLAND_COLOURS[mesh.islands[nav] % len(ISLAND_COLOURS)]
    return img


def top_down_png(r: dict, env, path: Path) -> Path:
    """Top-down picture of the scene's navmesh with the passages too narrow for the agent (red,
    with their widths), the goal objects' view points (their class colour) and the episode
    starts (black)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mesh, f = r["mesh"], r["figures"]
    h, w = mesh.ground.shape
    x0, y0 = mesh.origin_xy
    extent = (x0, x0 + w * mesh.cell_m, y0, y0 + h * mesh.cell_m)
    fig, ax = plt.subplots(figsize=(max(5.0, 9.0 * w / max(h, w)), max(5.0, 9.0 * h / max(h, w))))
    ax.imshow(navmesh_image(mesh), origin="lower", extent=extent, interpolation="nearest")
    eps = r.get("episodes", [])
    seen: set[str] = set()
    for ep in eps:
        if ep.object_category in seen:
            continue
        seen.add(ep.object_category)
        colour = PALETTE[GOAL_CATEGORIES.index(ep.object_category)] / 255.0
        vps = np.concatenate([g.view_points for g in ep.goals])
        ax.scatter(vps[:, 0], vps[:, 1], s=2, color=colour, label=f"{ep.object_category} view points")
    if eps:
        starts = np.array([ep.start_position for ep in eps])
        ax.scatter(starts[:, 0], starts[:, 1], s=14, color="black", marker="o", label="episode starts")
    for p in r["passages"]:
        ax.scatter(*p["at_xy"], s=60, facecolors="none", edgecolors="red", linewidths=1.5)
        ax.annotate(f"{p['width_m']:.2f} m", p["at_xy"], color="red", fontsize=8, xytext=(4, 4),
                    textcoords="offset points")
    g = r.get("generation", {})
    ax.set_title(f"{r['scene_id']}: floor {f['ground_m2']:.1f} m^2, navigable {f['navigable_m2']:.1f} m^2, "
                 f"{f['islands']} island(s); episodes {g.get('kept', 0)} kept, {g.get('unsolvable', 0)} unsolvable\n"
                 f"green/blue: islands, orange: too small, dark: not walkable, red: passages under "
                 f"{2 * (env.agent_radius_m + mesh.cell_m / 2):.2f} m", fontsize=8)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    if eps:
        ax.legend(fontsize=6, loc="upper right", markerscale=3)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def write_recording(r: dict, env, path: Path) -> Path:
    """``path`` (.rrd): the scene's mesh (``world/mesh``), its navmesh as cells at their floor
    height coloured as in the PNG (``world/navmesh``), the narrow passages (``world/passages``,
    labelled with their widths) and the episode starts (``world/starts``)."""
    from calnav.common.rerun_io import new_recording, require_rerun

    rr = require_rerun("check-scene's recording")
    scene, mesh = r["scene"], r["mesh"]
    rec = new_recording("calnav_check_scene", path)
    tris = scene.vertices[scene.triangles].reshape(-1, 3)
    rec.log("world/mesh", rr.Mesh3D(vertex_positions=tris, triangle_indices=np.arange(len(tris)).reshape(-1, 3),
                                    vertex_colors=np.repeat(scene.tri_albedo, 3, axis=0)), static=True)
    img = navmesh_image(mesh)
    cells = np.argwhere(mesh.ground | (mesh.eroded > 0))
    xy = mesh.origin_xy + (cells[:, ::-1] + 0.5) * mesh.cell_m
    z = np.nan_to_num(mesh.floor_z[cells[:, 0], cells[:, 1]], nan=scene.floor_z) + 0.01
    rec.log("world/navmesh", rr.Points3D(np.column_stack([xy, z]), colors=img[cells[:, 0], cells[:, 1]],
                                         radii=mesh.cell_m / 2), static=True)
    if r["passages"]:
        at = np.array([p["at_xy"] for p in r["passages"]])
        rec.log("world/passages", rr.Points3D(np.column_stack([at, np.full(len(at), scene.floor_z + 0.05)]),
                                              colors=[255, 0, 0], radii=0.06,
                                              labels=[f"{p['width_m']:.2f} m" for p in r["passages"]]), static=True)
    eps = r.get("episodes", [])
    if eps:
        starts = np.array([ep.start_position for ep in eps])
        rec.log("world/starts", rr.Points3D(np.column_stack([starts, np.full(len(starts), scene.floor_z + 0.1)]),
                                            colors=[0, 0, 0], radii=0.05,
                                            labels=[ep.object_category for ep in eps]), static=True)
    rec.flush()
    return path
