"""``calnav check-scene TARGET``: what the simulator makes of a scene, before any episode runs.

    calnav check-scene scans/apartment.ply --output runs/check     # one labelled mesh
    calnav check-scene data/scene_datasets/hm3d/val/00800-TEEsavR23oF/TEEsavR23oF.basis.glb   # an HM3D scene
    calnav check-scene scans/ --output runs/check                 # every scene of a scene_dir
    calnav check-scene house_val_0003 env.dataset.style=scanned   # a calnav house or its scan

Per scene: walkable floor, navigable area, islands (kept and dropped), passages the agent
cannot fit through (``envs.scene_check``), the episodes generated and rejected (and why), the
floor's height above the reference; a top-down picture (``<scene>.png``) and, with the viz
extra, a Rerun recording of the mesh with the navmesh, the passages and the episode starts
(``<scene>.rrd``). ``report.md`` / ``report.json`` hold every scene's figures. A scene that
cannot be used (nothing navigable, no episode) is reported, and the command then exits with a
one-line error naming it.
"""
from __future__ import annotations

import re
import traceback
from pathlib import Path

from calnav.eval.shorthands import load_command_config
from dataclasses import dataclass
from calnav.common.ranges import Range
from calnav.eval.arguments import REQUIRED, Command, arg

_PROCEDURAL = re.compile(r"^house_(train|val|test|calib)_\d+$")


def resolve_target(target: str) -> tuple[str | None, list[str]]:
    """(the ``env.dataset.scene_dir`` it names or None, scene ids) of a TARGET: a scene file, a
    directory of scene files, or a procedural scene id. ValueError naming the three forms
    otherwise."""
    from calnav.envs.hm3d import scene_id_of
    from calnav.envs.scene_files import scene_kind

    path = Path(target).expanduser()
    if path.is_file():   # (scene_kind refuses other suffixes and a .semantic.glb, naming the scene file)
        # the id the scene folder lists it by (envs.scene_files.scene_files_in): an HM3D / MP3D
        # .glb's is the scene's (TEEsavR23oF of TEEsavR23oF.basis.glb)
        return str(path.parent), [path.stem if scene_kind(path) in ("npz", "ply") else scene_id_of(path)]
    if path.is_dir():
        return str(path), []   # every scene of the directory
    if _PROCEDURAL.match(target):
        return None, [target]
    raise ValueError(f"{target!r} is neither a scene file (.ply / .npz / .glb), a directory of them, nor a calnav scene "
                     "id such as house_val_0003")


def target_scene_dir(target: str) -> str | None:
    """The ``env.dataset.scene_dir`` a TARGET names (None for a procedural scene id): the
    command table's shorthand for the target (``eval.cli.COMMANDS``)."""
    return resolve_target(target)[0]


def check_scene_configs(args) -> list:
    """The config ``calnav check-scene`` runs: the target's scene folder as ``env.dataset.scene_dir``."""
    return [load_command_config(args)]


def check_one(scene_id: str, env, episodes: int) -> dict:
    """Everything check-scene reports of one scene; ``"error"`` holds why a scene cannot be
    used (then the figures computed up to that point are kept)."""
    from calnav.envs.episodes import generate_scene_episodes
    from calnav.envs.navigation import NavGrid
    from calnav.envs.navmesh import build_navmesh
    from calnav.envs.render import Camera, Renderer
    from calnav.envs.scene_check import narrow_passages, navmesh_figures
    from calnav.envs.scenes import generation_seed, load_scene

    out: dict = {"scene_id": scene_id}
    scene = load_scene(scene_id, env.dataset)
    out["scene"], out["triangles"] = scene, len(scene.triangles)
    from calnav.envs.storey_detect import detect_storeys

    out["storeys"] = [round(float(z), 3) for z in (scene.meta.get("storey_z") or
                                                   detect_storeys(scene, env.navmesh.agent_max_slope_deg))]
    try:
        mesh = build_navmesh(scene, env)
    except ValueError as exc:
        out["error"] = str(exc)
        return out
    out["mesh"] = mesh
    out["figures"] = navmesh_figures(mesh, scene.floor_z)
    out["passages"] = narrow_passages(mesh, env.agent_radius_m)
    renderer = Renderer(scene, Camera.from_config(env))
    grid = NavGrid(navigable=mesh.navigable, origin_xy=mesh.origin_xy, cell_m=mesh.cell_m, floor_z=scene.floor_z,
                   free=mesh.ground, floor_heights=mesh.floor_z, islands=mesh.islands, stats=mesh.stats)
    counts: dict = {}
    try:
        eps = generate_scene_episodes(scene_id, scene, grid, renderer.raycasting_scene, env, episodes,
                                      generation_seed(scene_id, env.dataset.seed), report=counts)
    except ValueError as exc:
        out["error"] = str(exc)
        return out
    out["generation"] = counts
    out["episodes"] = eps
    if not eps:
        out["error"] = (f"every episode drawn was rejected ({counts['unsolvable']} unsolvable by the oracle, "
                        f"{counts['no_start']} category draws without a start)")
    return out


def scene_markdown(r: dict) -> str:
    """One scene's section of report.md."""
    lines = [f"## {r['scene_id']}", ""]
    if len(r.get("storeys", ())) > 1:
        lines.append(f"- storeys: {len(r['storeys'])}, floors at {', '.join(f'{z:.2f}' for z in r['storeys'])} m "
                     "(the run walks all of them; the figures below are the largest storey's)")
    f = r.get("figures")
    if f is not None:
        kept = ", ".join(f"{a:.1f}" for a in f["island_m2"])
        lines += [f"- walkable floor {f['ground_m2']:.1f} m^2, navigable {f['navigable_m2']:.1f} m^2 "
                  f"({f['navigable_fraction']:.0%} of it)",
                  f"- islands: {f['islands']} kept ({kept} m^2), {f['dropped_islands']} dropped as too small "
                  f"({f['dropped_m2']:.2f} m^2)",
                  f"- floor above the reference height: median {100 * f['floor_above_median_m']:.1f} cm, "
                  f"95th percentile {100 * f['floor_above_p95_m']:.1f} cm",
                  f"- walkable surfaces: {f['surfaces']}, {f['ground_surfaces']} of them at the storey's height "
                  "(the others: table tops, seats, bed tops, wall tops)"]
        for p in r["passages"]:
            fate = "kept as its own island" if p["kept"] else "dropped"
            lines.append(f"- passage {p['width_m']:.2f} m wide (needs {p['needed_m']:.2f} m) at "
                         f"({p['at_xy'][0]:.2f}, {p['at_xy'][1]:.2f}) between {p['joins_m2']:.1f} m^2 and a "
                         f"{p['piece_m2']:.2f} m^2 piece ({fate})")
    g = r.get("generation")
    if g is not None:
        lines.append(f"- episodes: {g['kept']} generated of {g['drawn']} drawn; rejected: {g['unsolvable']} "
                     f"unsolvable by the discrete-action oracle, {g['no_start']} category draws without a start")
    if "error" in r:
        lines.append(f"- **cannot be used**: {r['error']}")
    return "\n".join(lines) + "\n"


def _json_row(r: dict) -> dict:
    keep = ("scene_id", "triangles", "storeys", "figures", "passages", "generation", "error")
    return {k: r[k] for k in keep if k in r}


def main_check_scene(args, configs) -> None:
    from calnav.common.atomic import write_json_atomic, write_text_atomic
    from calnav.envs.scenes import split_scene_ids
    from calnav.eval.results_dir import ResultsDir, writing
    from calnav.eval.scanning.check_figure import top_down_png, write_recording

    cfg = configs[0]
    env = cfg.env
    _, ids = resolve_target(args.target)
    if not ids:   # a directory: every split's scenes, once
        ids = sorted({s for split in ("train", "val", "test") for s in _split_ids(split_scene_ids, split, env)})
    rerun = _has_rerun()
    out = Path(args.output)
    rows, problems = [], []
    with ResultsDir(out, cfg, force=args.force, discard=("report.md", "report.json"), files=("report.md",)):
        for sid in ids:
            try:
                r = check_one(sid, env, args.episodes)
            except ValueError as exc:   # a scene file that does not load
                r = {"scene_id": sid, "error": str(exc)}
            except Exception as exc:    # noqa: BLE001 -- reported with the scene, the others still run
                r = {"scene_id": sid, "error": f"{type(exc).__name__}: {exc}",
                     "traceback": traceback.format_exc(limit=4)}
            name = re.sub(r"[^\w.-]", "_", sid)
            with writing(out / f"{name}.png"):
                if "mesh" in r:
                    r["png"] = str(top_down_png(r, env, out / f"{name}.png"))
                    if rerun:
                        r["rrd"] = str(write_recording(r, env, out / f"{name}.rrd"))
            print(scene_markdown(r))
            rows.append(r)
            if "error" in r:
                problems.append(f"{sid}: {r['error']}")
        with writing(out / "report.md"):
            write_text_atomic(out / "report.md", "# calnav check-scene\n\n" + "\n".join(scene_markdown(r) for r in rows))
            write_json_atomic(out / "report.json", {"scenes": [_json_row(r) for r in rows]})
    pictures = [Path(r[k]).name for r in rows for k in ("png", "rrd") if k in r]   # the files written, no others
    note = " (Rerun recordings need the [viz] extra)" if pictures and not rerun else ""
    print(f"results: {out}/{', '.join(['report.md', 'report.json', *pictures])}{note}")
    if problems:
        raise ValueError(f"{len(problems)} of {len(rows)} scenes cannot be used; {problems[0]}")


def _split_ids(split_scene_ids, split: str, env) -> list[str]:
    """A user scene_dir's ids of ``split`` ([] when it has split folders without this one)."""
    try:
        return split_scene_ids(split, env.dataset)
    except ValueError:
        return []


def _has_rerun() -> bool:
    import importlib.util

    return importlib.util.find_spec("rerun") is not None


@dataclass
class CheckSceneArgs:
    """``calnav check-scene``'s flags."""

    target: str = arg(REQUIRED, "a scene file (.ply / .npz / .glb), a directory of them, or a calnav scene id "
                                "(house_val_0003; with env.dataset.style=scanned its scan)", positional=True,
                      sets="env.dataset.scene_dir", convert=target_scene_dir)   # a scene file's or directory's
    episodes: int = arg(20, "episodes to generate per scene (default 20)", range=Range(1, 100_000, "episodes"))
    output: str = arg("runs/check_scene", "results directory")
    force: bool = arg(False, "discard results of a different config in --output")


COMMAND = Command(CheckSceneArgs, main_check_scene, check_scene_configs, config="configs/objectnav.yaml",
                  checks=("run",))   # runs no agent: loads scenes, builds navmeshes, draws episodes
