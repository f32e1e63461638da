"""``calnav calibrate-map``: the paper's map-calibration study as one resumable command.

Stages (each writes its results before the next starts; a rerun skips finished work):

1. record  -- scan every calibration-train / -validation / test house, segment each frame with
   every segmenter, keep the voxel observation caches and a pixel sample
   (``eval.calibration.record``): ``<out>/scenes/<segmenter>/<scene>.{cache,pixels}.npz``.
2. fit     -- per segmenter, on calibration-train houses: 2D temperature (pixel NLL), 3D
   temperature and 3D vector scaling per strategy (voxel mECE of the fused map), the
   mECE-vs-temperature curve of every fixed strategy (``eval.calibration.tau_curve``), and one
   GLFS per ``study.glfs_variants`` entry (model selection on calibration-validation houses):
   ``<out>/fits/<segmenter>/``.
3. score   -- per segmenter and test house, the calibration statistics of every
   (strategy, calibration) map, and the predictions on void voxels (the authors' mIoU):
   ``<out>/scores/<segmenter>/<scene>.npz``.
4. report  -- ``results.csv``, ``results.md``, calibration-vs-accuracy, GLFS trade-off,
   reliability and error-vs-confidence plots (``eval.calibration.report``), and the
   qualitative RBU-vs-GLFS views of one test house (``eval.calibration.figures``).

Rows: every strategy x calibration method (``none``, ``temperature_2d``, ``temperature_3d``,
``vector_3d``) for the fixed strategies; GLFS once per variant, the calibration column naming
the variant (GLFS with untrained identity parameters is naive averaging, already a row).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from calnav.common.atomic import atomic_path, write_json_atomic
from calnav.eval.backends import check_backend
from calnav.eval.calibration.record import ROLES, load_role, record_houses, role_scene_ids, scene_seed
from calnav.eval.config import Config, ConfigError
from calnav.eval.results_dir import ResultsDir, check_output_file, writing
from calnav.eval.sections import GLFSVariant
from calnav.eval.shorthands import load_command_config
from calnav.mapping import metrics
from calnav.mapping.calibration.fit import MapObjective, fit_temperature_2d, fit_temperature_3d, fit_vector_3d
from calnav.mapping.calibration.flat_obs import FlatObservations
from calnav.mapping.glfs import GLFSParams
from calnav.mapping.calibration.glfs_train import GLFSModel, train_glfs
from dataclasses import dataclass
from calnav.eval.arguments import REQUIRED, Command, arg
from calnav.eval.config import CALIBRATION_SECTIONS
from calnav.eval.sections import QUICK_PRESET
from calnav.eval.shorthands import fixed

VOID = -1   # label of void voxels in the observation caches


def methods(cfg: Config) -> list[tuple[str, str]]:
    """(strategy, calibration) pairs of the study, in table order."""
    out = []
    for s in cfg.study.strategies:
        out += [(s, v.name) for v in cfg.study.glfs_variants] if s == "glfs" else [(s, c) for c in cfg.study.calibrations]
    return out


# ------------------------------------------------------------------------------- fit
class Fits:
    """The fitted parameters of one segmenter, saved as they are produced (``fits.json`` +
    ``glfs_<variant>.json``) so an interrupted run resumes after the last finished fit."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.path = folder / "fits.json"
        self.data = json.loads(self.path.read_text()) if self.path.exists() else {}

    def get(self, key: str):
        return self.data.get(key)

    def put(self, key: str, value) -> None:
        self.data[key] = value
        write_json_atomic(self.path, self.data, indent=1)

    def glfs_path(self, variant: str) -> Path:
        return self.folder / f"glfs_{variant}.json"

    def temperature(self, strategy: str, calibration: str):
        """The logit temperature (float or (K,) list) a (strategy, calibration) row uses."""
        if strategy == "glfs":             # calibration names the GLFS variant
            return GLFSParams.load(self.glfs_path(calibration)).tau.tolist()
        if calibration == "none":
            return 1.0
        if calibration == "temperature_2d":
            return self.data["temperature_2d"]["temperature"]
        return self.data[f"{calibration}/{strategy}"]["temperature"]


def fit_segmenter(cfg: Config, out: Path, segmenter: str, ids: dict[str, list[str]],
                  progress: bool = True) -> Fits:
    from tqdm import tqdm

    from calnav.eval.calibration.tau_curve import temperature_curve

    st = cfg.study
    fits = Fits(out / "fits" / segmenter)
    caches, pix_logits, pix_labels = load_role(out, segmenter, ids["calib_train"])
    if fits.get("temperature_2d") is None and "temperature_2d" in st.calibrations:
        r = fit_temperature_2d(pix_logits, pix_labels)
        fits.put("temperature_2d", {"temperature": r.temperature, "nll": r.objective, "pixels": int(len(pix_labels))})
    fixed = [s for s in st.strategies if s != "glfs"]
    todo = [(c, s) for c in ("temperature_3d", "vector_3d") if c in st.calibrations for s in fixed
            if fits.get(f"{c}/{s}") is None]
    if todo:
        flat = FlatObservations.from_caches(caches, max_voxels=st.fit_max_voxels, seed=cfg.run.seed)
        for c, s in tqdm(todo, desc=f"fit 3D scaling ({segmenter})", unit="fit", disable=not progress):
            if c == "temperature_3d":
                r = fit_temperature_3d(flat, s, grid_points=st.grid_points, refine_iters=st.refine_iters)
            else:
                init = fits.get(f"temperature_3d/{s}")
                init = init["temperature"] if init else fit_temperature_3d(flat, s, grid_points=st.grid_points,
                                                                         refine_iters=st.refine_iters).temperature
                r = fit_vector_3d(flat, s, init=init, sweeps=st.vector_sweeps, refine_iters=st.vector_refine_iters)
            t = r.temperature.tolist() if isinstance(r.temperature, np.ndarray) else r.temperature
            fits.put(f"{c}/{s}", {"temperature": t, "mece_fit": r.objective, "mece_tau1": MapObjective(flat, s)(1.0),
                                  "evaluations": r.evaluations, "flat": r.flat, "voxels": flat.num_voxels})
        del flat
    if fixed and fits.get("tau_curve") is None:
        flat = FlatObservations.from_caches(caches, max_voxels=st.fit_max_voxels, seed=cfg.run.seed)
        fits.put("tau_curve", temperature_curve(flat, fixed, st.tau_curve_points, progress=progress))
        del flat
    if "glfs" in st.strategies:
        fit_glfs_variants(cfg, out, segmenter, ids, fits, caches, st.glfs_variants, progress)
    return fits


def fit_glfs_variants(cfg: Config, out: Path, segmenter: str, ids: dict[str, list[str]], fits: Fits,
                      caches: list, variants: list[GLFSVariant], progress: bool = True) -> None:
    """Train every GLFS variant without a saved parameter file (train / validation voxels are
    loaded once and shared)."""
    st, configs = cfg.study, cfg.glfs_configs()
    todo = [v for v in variants if not fits.glfs_path(v.name).exists()]
    if not todo:
        return
    train = FlatObservations.from_caches(caches, max_voxels=st.glfs_max_voxels, seed=cfg.run.seed)
    val = FlatObservations.from_caches(load_role(out, segmenter, ids["calib_val"])[0],
                                       max_voxels=st.glfs_max_voxels, seed=cfg.run.seed)
    for v in todo:
        params, hist = train_glfs(train, val, configs[v.name], class_names=caches[0].class_names, progress=progress)
        fits.put(f"glfs/{v.name}", {**hist.to_dict(), "g": params.g, "eps": params.eps,
                                    "train_voxels": train.num_voxels, "val_voxels": val.num_voxels})
        params.save(fits.glfs_path(v.name))



# ----------------------------------------------------------------------------- score
def _stats_arrays(stats: metrics.CalibrationStats) -> dict[str, np.ndarray]:
    return {"count": stats.count, "conf_sum": stats.conf_sum, "brier_sum": np.array(stats.brier_sum),
            "void_pred": stats.void_pred}


def score_scene(cfg: Config, out: Path, segmenter: str, scene_id: str, fits: Fits) -> Path:
    """Calibration statistics of every (strategy, calibration) map of one test house (labelled
    voxels), with each map's argmax counts on the void voxels (``void_pred``)."""
    path = out / "scores" / segmenter / f"{scene_id}.npz"
    if path.exists():
        return path
    caches, _, _ = load_role(out, segmenter, [scene_id])
    flat = FlatObservations.from_caches(caches, ignore_index=VOID, keep_void=True)
    labels = flat.labels.numpy()
    arrays = {}
    for strategy, calibration in methods(cfg):
        with torch.no_grad():
            if strategy == "glfs":
                probs = GLFSModel.from_params(GLFSParams.load(fits.glfs_path(calibration)))(flat).numpy()
            else:
                probs = MapObjective(flat, strategy).probs(np.asarray(fits.temperature(strategy, calibration), np.float32))
        stats = metrics.CalibrationStats(flat.num_classes).update(probs, labels, ignore_index=VOID, count_ignored=True)
        for k, v in _stats_arrays(stats).items():
            arrays[f"{strategy}/{calibration}/{k}"] = v
    with atomic_path(path) as tmp:
        np.savez_compressed(tmp, n_voxels=np.array(int((labels != VOID).sum())), **arrays)
    return path


def merged_stats(cfg: Config, paths: list[Path], num_classes: int
                 ) -> tuple[dict[tuple[str, str], metrics.CalibrationStats], int]:
    """Per-(strategy, calibration) statistics summed over houses, and the number of voxels."""
    out = {m: metrics.CalibrationStats(num_classes) for m in methods(cfg)}
    n_voxels = 0
    for p in paths:
        with np.load(p) as d:
            n_voxels += int(d["n_voxels"])
            for (s, c), st in out.items():
                st.count += d[f"{s}/{c}/count"]
                st.conf_sum += d[f"{s}/{c}/conf_sum"]
                st.brier_sum += float(d[f"{s}/{c}/brier_sum"])
                st.void_pred += d[f"{s}/{c}/void_pred"]
    return out, n_voxels


def pixel_mece(logits: np.ndarray, labels: np.ndarray, temperature) -> float:
    z = torch.from_numpy(logits) / torch.as_tensor(np.asarray(temperature, np.float32))
    return metrics.mece(torch.softmax(z, dim=1).numpy(), labels)


# ------------------------------------------------------------------------------- run
# What --force deletes from a directory that holds another config's study.
STUDY_RESULTS: tuple[str, ...] = ("scenes", "fits", "scores", "results.csv", "results.md")


def _check_roles(ids: dict[str, list[str]], roles=ROLES) -> None:
    for role in roles:
        if not ids[role]:
            raise ValueError(f"no {role} houses (check study.*_scenes and env.dataset.scene_dir)")


def run_calibrate_map(cfg: Config, out: Path, force: bool = False, progress: bool = True) -> list[dict]:
    """Run (or resume) the whole study; returns the result rows (also written to ``out``)."""
    from tqdm import tqdm

    from calnav.agent.segmenters import make_segmenter
    from calnav.eval.calibration.report import write_report
    from calnav.eval.calibration.tau_curve import write_tau_curves

    ids = role_scene_ids(cfg)
    _check_roles(ids)
    check_backend(cfg.run.backend, cfg.run.ray_address)
    segs = {n: make_segmenter(n, cfg.segmenter, device=cfg.run.device) for n in cfg.study.segmenters}
    houses = {sid: scene_seed(sid, cfg.run.seed) for role in ROLES for sid in ids[role]}
    with ResultsDir(out, cfg, force=force, discard=STUDY_RESULTS, files=("results.csv",)):
        record_houses(cfg, houses, tuple(segs), out, progress)
        rows, all_stats, histories, curves, fitted = [], {}, {}, {}, {}
        for name in cfg.study.segmenters:
            fits = fit_segmenter(cfg, out, name, ids, progress)
            paths = [score_scene(cfg, out, name, sid, fits)
                     for sid in tqdm(ids["test"], desc=f"score test maps ({name})", unit="house", disable=not progress)]
            k = segs[name].num_classes
            stats, n_vox = merged_stats(cfg, paths, k)
            _, pix_logits, pix_labels = load_role(out, name, ids["test"])
            for (s, c), st in stats.items():
                rows.append({"segmenter": name, "strategy": s, "calibration": c, "miou": st.miou(),
                             "miou_authors": st.miou(convention="authors", exclude=cfg.study.authors_miou_exclude),
                             "ece": st.ece(), "tl_ece": st.tl_ece(), "mece": st.mece(), "brier": st.brier(),
                             "pixel_mece": pixel_mece(pix_logits, pix_labels, fits.temperature(s, c)), "n_voxels": n_vox})
            all_stats[name] = stats
            histories[name] = {v.name: fits.get(f"glfs/{v.name}") for v in cfg.study.glfs_variants
                               if fits.get(f"glfs/{v.name}")}
            if fits.get("tau_curve"):
                curves[name] = fits.get("tau_curve")
                fitted[name] = {s: fits.get(f"temperature_3d/{s}")["temperature"] for s in cfg.study.strategies
                                if fits.get(f"temperature_3d/{s}")}
            picks = write_report(out, rows, all_stats, segs[name].class_names, histories)
            write_tau_curves(out, curves, fitted)
            # the example views render the house mesh from the scan's poses: calnav houses only
            if "glfs" in cfg.study.strategies and not cfg.sequences.list:
                variant = picks.get(name, {}).get("pick") or cfg.study.glfs_variants[0].name
                qualitative(cfg, out, name, segs[name], ids["test"][cfg.study.figure_scene], fits, variant)
    return rows


def qualitative(cfg: Config, out: Path, segmenter: str, seg, scene_id: str, fits: Fits,
                variant: str) -> None:
    """The RBU-vs-GLFS views of one test house (skipped when already written for ``variant``)."""
    from calnav.eval.calibration.figures import write_qualitative

    done = out / f"qualitative_{segmenter}.json"
    if done.exists() and json.loads(done.read_text()).get("glfs_variant") == variant:
        return
    write_qualitative(cfg, out, segmenter, seg, scene_id, scene_seed(scene_id, cfg.run.seed),
                      GLFSParams.load(fits.glfs_path(variant)), variant)


def calibrate_map_configs(args) -> list[Config]:
    """The config ``calnav calibrate-map`` runs, with the command's shorthands: ``--quick``'s
    preset (``eval.sections.QUICK_PRESET``) and ``--sequences LIST`` as ``sequences.list``
    (resolved against the working directory)."""
    return [load_command_config(args)]


def main_calibrate_map(args, configs: list[Config]) -> None:
    """``configs``: ``calibrate_map_configs(args)``, checked by the preflight."""
    if getattr(args, "page", None):   # re-render the docs' tables from committed records: no study runs
        from calnav.eval.calibration.page import render_pages

        render_pages(args.page, Path.cwd())
        return
    cfg = configs[0]
    out = Path(args.output or (cfg.run.output_dir + "_quick" if args.quick else cfg.run.output_dir))
    rows = run_calibrate_map(cfg, out, force=args.force)
    from calnav.eval.calibration.report import format_table

    print(format_table(rows))
    print(f"\nresults: {out / 'results.csv'}, {out / 'results.md'}, plots in {out}")


def fit_glfs_configs(args) -> list[Config]:
    """The config ``calnav fit-glfs`` runs: the study's, with only ``--segmenter`` and GLFS (the
    command's shorthands: ``study.segmenters=[SEGMENTER]``, ``study.strategies=[glfs]``)."""
    return [load_command_config(args)]


def main_fit_glfs(args, configs: list[Config]) -> None:
    """Record the calibration-train / -validation scans of one segmenter and train one GLFS
    variant (``--variant``, default the first of ``study.glfs_variants``). ``configs``:
    ``fit_glfs_configs(args)``, checked by the preflight."""
    check_output_file(args.output)   # written at the end: a bad path must not cost the training first
    from calnav.agent.segmenters import make_segmenter

    cfg = configs[0]
    variants = {v.name: v for v in cfg.study.glfs_variants}
    name = args.variant or cfg.study.glfs_variants[0].name
    if name not in variants:
        raise ConfigError(f"unknown GLFS variant {name!r}; valid (study.glfs_variants): {', '.join(variants)}")
    work = Path(args.work_dir or cfg.run.output_dir)
    ids = role_scene_ids(cfg)
    _check_roles(ids, ("calib_train", "calib_val"))
    make_segmenter(args.segmenter, cfg.segmenter, device=cfg.run.device)  # a bad name or weights file fails here, before any work
    check_backend(cfg.run.backend, cfg.run.ray_address)
    houses = {sid: scene_seed(sid, cfg.run.seed) for sid in ids["calib_train"] + ids["calib_val"]}
    with ResultsDir(work, cfg, discard=STUDY_RESULTS, files=(), option="--work-dir", segmenters=(args.segmenter,),
                    can_force=False):
        record_houses(cfg, houses, (args.segmenter,), work)
        fits = Fits(work / "fits" / args.segmenter)
        caches = load_role(work, args.segmenter, ids["calib_train"])[0]
        fit_glfs_variants(cfg, work, args.segmenter, ids, fits, caches, [variants[name]])
        params = GLFSParams.load(fits.glfs_path(name))
    with writing(args.output):
        dest = params.save(args.output)
    print(f"GLFS parameters: tau mean {params.tau.mean():.3f}, G {params.g:.3f}, eps {params.eps:.3f} -> {dest}")
    hist = fits.get(f"glfs/{name}")   # the kept checkpoint's validation figures (the bar shows the last epoch's)
    if hist and hist.get("val_miou"):
        k = int(hist["best_check"])
        print(f"kept: validation check {k} of {len(hist['val_miou']) - 1} (epoch {hist['best_epoch']:.2f}, "
              f"glfs.selection={cfg.glfs_configs()[name].selection}): "
              f"validation mIoU {hist['val_miou'][k]:.3f}, mECE {hist['val_mece'][k]:.3f}")


@dataclass
class CalibrateMapArgs:
    """``calnav calibrate-map``'s flags."""

    quick: bool = arg(False, "small preset (3/1/3 houses, short fits), <= 5 minutes: sets the study / scan / glfs "
                             "keys of eval.sections.QUICK_PRESET", preset=QUICK_PRESET)
    output: str | None = arg(None, "results directory (default: run.output_dir)")
    force: bool = arg(False, "discard results of a different config in --output")
    sequences: str | None = arg(None, "recorded sequences instead of calnav's houses: a list file of '<role> <dir> "
                                      "[layout]' lines (role: calib_train | calib_val | test); shorthand for "
                                      "sequences.list=LIST", metavar="LIST", sets="sequences.list",
                                convert=lambda path: str(Path(path).resolve()))   # relative to where calnav started
    page: list[str] = arg([], "render FILE's '<!-- calnav calibrate-map DIR -->' tables from the committed records "
                              "under DIR (DIR/clean/results.csv, DIR/scanned/results.csv) instead of running the "
                              "study; repeatable", metavar="FILE", repeat=True)


@dataclass
class FitGlfsArgs:
    """``calnav fit-glfs``'s flags."""

    segmenter: str = arg(REQUIRED, "segmenter whose observations GLFS is fitted to (any agent.segmenter spec; "
                                   "segmenter section); shorthand for study.segmenters=[SEGMENTER]",
                         metavar="SEGMENTER", sets="study.segmenters", convert=lambda name: f"[{name}]")
    output: str = arg(REQUIRED, "GLFS parameter file (.json / .npz) for mapping.glfs_params")
    work_dir: str | None = arg(None, "where scans are kept (default: run.output_dir)")
    variant: str | None = arg(None, "GLFS variant of study.glfs_variants to train (default: the first, 'learned' = "
                                    "the glfs section)")


CALIBRATE_MAP = Command(CalibrateMapArgs, main_calibrate_map, calibrate_map_configs,
                        config="configs/calibrate_map.yaml", sections=CALIBRATION_SECTIONS)
FIT_GLFS = Command(FitGlfsArgs, main_fit_glfs, fit_glfs_configs, config="configs/calibrate_map.yaml",
                   sections=CALIBRATION_SECTIONS,
                   fixed=(fixed("study.strategies", "[glfs]"),))   # it fits GLFS only
