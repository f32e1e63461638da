"""The paper's qualitative figures (Fig. 1 and Fig. 5): one test house mapped with RBU and with
GLFS, rendered from the same cameras, so a reader sees *where* each map is wrong and how
confident it is there.

The house is scanned again with the study's trajectory (same seed as its recording), every
frame is segmented once and integrated into two ``SemanticVoxelMap``s (raw RBU, and GLFS with
the given parameters). Views: ``CANDIDATE_VIEWS`` scan poses, evenly spaced, are rendered at the
scan resolution and the ``figure_views`` with the most wrong pixels (either map) are kept --
the figure shows the errors on purpose, the error statistics of every candidate are written
too, so the choice hides nothing. Each kept view is rendered at ``study.figure_resolution``
(``SemanticVoxelMap.render_semantics``) against the true labels of the house mesh
(``mapping.ground_truth.LabelledMesh.render``).

Per view (a row): ground truth | per map: predicted class, confidence (top-label probability),
errors (wrong pixels coloured by their confidence, correct ones grey). Written:
``qualitative_<segmenter>.png`` and ``qualitative_<segmenter>.json`` (per view and map: error
rate, mean confidence of wrong and of correct pixels), and with the ``[viz]`` extra
``qualitative_<segmenter>.rrd``: the house in 3D, RBU and GLFS side by side (``write_recording``).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from calnav.common.atomic import undefined_as_null, write_json_atomic

CANDIDATE_VIEWS = 24          # scan poses scored to choose the views shown
CORRECT_GREY = 0.82           # grey level of correct pixels in the error panel
NO_DATA = 1.0                 # white where the map has no semantics or the truth is void


def _view_stats(probs: np.ndarray, valid: np.ndarray, truth: np.ndarray) -> dict:
    """Pixels scored: map has semantics and the truth is a class. probs (H, W, K), valid (H, W),
    truth (H, W) int (-1 void)."""
    scored = valid & (truth >= 0)
    pred, conf = probs.argmax(axis=2), probs.max(axis=2)
    wrong = scored & (pred != truth)
    right = scored & (pred == truth)
    mean = lambda m: float(conf[m].mean()) if m.any() else float("nan")  # noqa: E731
    return {"pixels": int(scored.sum()), "error_rate": float(wrong.sum() / max(scored.sum(), 1)),
            "conf_wrong": mean(wrong), "conf_correct": mean(right)}


def build_maps(cfg, scene_id: str, seed: int, segmenter, glfs_params) -> tuple:
    """(scene, poses (F, 4, 4), {label: SemanticVoxelMap}) of one scanned house."""
    from calnav.eval.calibration.record import SEGMENT_BATCH, HouseScan
    from calnav.mapping.voxel_map import SemanticVoxelMap

    scan = HouseScan(cfg, scene_id, seed)
    scene, intrinsics, poses = scan.scene, scan.intrinsics, np.asarray(scan.poses)
    names = tuple(scene.class_names)
    k = len(names)
    maps = {"RBU": SemanticVoxelMap(k, dataclasses.replace(cfg.mapping, fusion="rbu", weighting="none", glfs_params=""),
                                    class_names=names),
            "GLFS": SemanticVoxelMap(k, dataclasses.replace(cfg.mapping, fusion="glfs", weighting="auto", glfs_params=""),
                                     class_names=names, glfs_params=glfs_params)}
    for rgb, depth, sem, batch_poses in scan.batches(SEGMENT_BATCH):   # rendered a batch at a time
        for i, lg in enumerate(segmenter.segment_batch(rgb, depth, semantic=sem, poses=batch_poses)):
            for m in maps.values():
                m.integrate(depth[i], intrinsics, batch_poses[i], lg)
    return scene, poses, maps


def render_views(cfg, scene, poses: np.ndarray, maps: dict, n_views: int, resolution: tuple[int, int]) -> list[dict]:
    """The ``n_views`` candidate poses with the most wrong pixels, rendered at ``resolution``:
    [{"pose_index", "truth" (H, W), label: (probs, valid), "stats": {label: _view_stats}}]."""
    from calnav.envs.render import Camera
    from calnav.mapping.ground_truth import LabelledMesh

    mesh = LabelledMesh(scene.vertices, scene.triangles, scene.tri_class)
    depth_max = cfg.mapping.depth_max_m

    def render(pose_index: int, w: int, h: int) -> dict:
        intr = Camera(width=w, height=h, hfov_deg=cfg.env.hfov_deg).intrinsics
        _, truth = mesh.render(intr, poses[pose_index], w, h, depth_max_m=depth_max)
        view = {"pose_index": int(pose_index), "truth": truth, "stats": {}}
        for label, m in maps.items():
            probs, valid = m.render_semantics(intr, poses[pose_index], w, h)
            view[label] = (probs, valid)
            view["stats"][label] = _view_stats(probs, valid, truth)
        return view

    w0, h0 = cfg.env.resolution
    candidates = np.linspace(0, len(poses) - 1, min(CANDIDATE_VIEWS, len(poses))).round().astype(int)
    scored = [render(int(i), w0, h0) for i in candidates]
    wrong = [sum(v["stats"][lb]["error_rate"] * v["stats"][lb]["pixels"] for lb in maps) for v in scored]
    keep = sorted(np.argsort(wrong)[::-1][:n_views])
    w, h = resolution
    views = [render(scored[i]["pose_index"], w, h) for i in keep]
    views[0]["candidates"] = [{"pose_index": v["pose_index"], **{lb: v["stats"][lb] for lb in maps}} for v in scored]
    return views


def plot_qualitative(views: list[dict], class_names, path: Path, title: str, labels: dict[str, str]) -> Path:
    """One row per view: truth | per map: class, confidence, errors. ``labels``: {map key: title}."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    from calnav.envs.semantics import PALETTE

    cols = 1 + 3 * len(labels)
    fig, axes = plt.subplots(len(views), cols, figsize=(2.3 * cols, 1.95 * len(views) + 1.2), squeeze=False)
    palette = PALETTE.astype(np.float64) / 255.0
    cmap = plt.get_cmap("inferno")
    for r, v in enumerate(views):
        truth = v["truth"]
        img = np.full(truth.shape + (3,), NO_DATA)
        img[truth >= 0] = palette[truth[truth >= 0]]
        axes[r, 0].imshow(img)
        axes[r, 0].set_title("ground truth" if r == 0 else "", fontsize=8)
        axes[r, 0].set_ylabel(f"view {v['pose_index']}", fontsize=8)
        for j, (key, name) in enumerate(labels.items()):
            probs, valid = v[key]
            pred, conf = probs.argmax(axis=2), probs.max(axis=2)
            cls = np.full(truth.shape + (3,), NO_DATA)
            cls[valid] = palette[pred[valid]]
            cimg = np.where(valid, conf, np.nan)
            err = np.full(truth.shape + (3,), NO_DATA)
            scored = valid & (truth >= 0)
            err[scored] = CORRECT_GREY
            wrong = scored & (pred != truth)
            err[wrong] = cmap(conf[wrong])[:, :3]
            s = v["stats"][key]
            a0, a1, a2 = axes[r, 1 + 3 * j], axes[r, 2 + 3 * j], axes[r, 3 + 3 * j]
            a0.imshow(cls)
            im = a1.imshow(cimg, vmin=0, vmax=1, cmap="viridis")
            a2.imshow(err)
            a2.set_xlabel(f"wrong {100 * s['error_rate']:.0f}%: conf {s['conf_wrong']:.2f}\n"
                          f"(correct: {s['conf_correct']:.2f})", fontsize=7)
            if r == 0:
                a0.set_title(f"{name}\nclass", fontsize=8)
                a1.set_title(f"{name}\nconfidence", fontsize=8)
                a2.set_title(f"{name}\nerrors, coloured by conf.", fontsize=8)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    present = sorted({int(c) for v in views for c in np.unique(v["truth"]) if c >= 0})
    handles = [Patch(color=palette[c], label=class_names[c]) for c in present]
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 9), fontsize=7, frameon=False)
    fig.suptitle(title, fontsize=10)
    fig.subplots_adjust(left=0.03, right=0.9, bottom=0.12, top=0.88, wspace=0.05, hspace=0.3)
    cb = fig.colorbar(im, cax=fig.add_axes((0.915, 0.55, 0.008, 0.3)))
    cb.set_label("confidence", fontsize=7)
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(0, 1))
    cb = fig.colorbar(sm, cax=fig.add_axes((0.915, 0.15, 0.008, 0.3)))
    cb.set_label("confidence of a wrong pixel", fontsize=7)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def write_qualitative(cfg, out: Path, segmenter_name: str, segmenter, scene_id: str, seed: int,
                      glfs_params, glfs_label: str) -> list[Path]:
    """Build, render, plot and summarise the RBU-vs-GLFS views of ``scene_id``."""
    scene, poses, maps = build_maps(cfg, scene_id, seed, segmenter, glfs_params)
    st = cfg.study
    views = render_views(cfg, scene, poses, maps, st.figure_views, st.figure_resolution)
    png = plot_qualitative(views, scene.class_names, out / f"qualitative_{segmenter_name}.png",
                           f"{segmenter_name}, test house {scene_id}: raw RBU vs GLFS ({glfs_label})",
                           {"RBU": "RBU", "GLFS": f"GLFS {glfs_label}"})
    summary = {"scene": scene_id, "glfs_variant": glfs_label, "resolution": list(st.figure_resolution),
               "views": [{"pose_index": v["pose_index"], **v["stats"]} for v in views],
               "candidates": views[0]["candidates"]}
    js = out / f"qualitative_{segmenter_name}.json"
    write_json_atomic(js, undefined_as_null(summary), indent=1)
    rrd = write_recording(cfg, out / f"qualitative_{segmenter_name}.rrd", scene, poses, maps,
                          {"RBU": "rbu", "GLFS": "glfs"})
    return [png, js] + ([rrd] if rrd else [])


def write_recording(cfg, path: Path, scene, poses: np.ndarray, maps: dict, trees: dict[str, str]) -> Path | None:
    """The figure's house in 3D (``[viz]`` extra; without it a note, no file): one entity tree
    per map (``trees``: {map key: tree}) with ``<tree>/world/map/class`` / ``confidence``
    (``common.rerun_io.log_voxels``) and ``<tree>/world/map/correct`` / ``wrong`` (the voxels
    against the house's labels, coloured by confidence: RBU's bright wrong voxels are its
    over-confidence), plus the house mesh coloured by class and the scan's camera path."""
    try:
        from calnav.common import rerun_io

        rr = rerun_io.require_rerun()
    except ValueError as exc:
        print(f"calibrate-map: no {path.name}: {exc}")
        return None
    from calnav.envs.semantics import PALETTE
    from calnav.mapping.ground_truth import voxel_labels

    names = tuple(scene.class_names)
    palette = PALETTE[:len(names)].astype(np.uint8)
    rec = rerun_io.new_recording("calnav calibrate-map", path, names, palette)
    vox = cfg.mapping.voxel_size_m
    colours = np.where((scene.tri_class >= 0)[:, None], palette[np.clip(scene.tri_class, 0, len(names) - 1)], 128)
    rec.log("world/mesh", rr.Mesh3D(vertex_positions=scene.vertices[scene.triangles].reshape(-1, 3).astype(np.float32),
                                    vertex_colors=np.repeat(colours, 3, axis=0).astype(np.uint8)), static=True)
    rec.log("world/scan", rr.LineStrips3D([poses[:, :3, 3].astype(np.float32)]), static=True)
    for key, tree in trees.items():
        coords, probs = maps[key].voxels()
        rerun_io.log_voxels(rec, f"{tree}/world/map", coords, probs, vox, palette, static=True)
        labels = voxel_labels(coords, scene.vertices, scene.triangles, scene.tri_class, None, vox)  # as the study
        pred, conf = probs.argmax(axis=1), probs.max(axis=1).astype(np.float32)
        for name, sel in (("correct", (labels >= 0) & (pred == labels)), ("wrong", (labels >= 0) & (pred != labels))):
            rerun_io.log_mask_points(rec, f"{tree}/world/map/{name}", coords[sel],
                                     rerun_io.confidence_colours(conf[sel], len(names)), vox, {"confidence": conf[sel]},
                                     static=True)
    rec.flush()
    rec.disconnect()
    return path
