"""``calnav train-predictor``: the target predictor (``agent.prediction``) trained on
``calnav collect-maps`` output, with PEANUT's loss -- binary cross-entropy per cell and goal
category, the target restricted to cells the input has not explored (PEANUT:
``gt * (1 - explored)``) -- counted on the unexplored cells within ``PredictorSpec.near_m`` (4 m) of the explored
area, where the agent chooses its goals (the far ones are mostly outside the house: negatives geometry alone predicts) with goal
cells weighted ``predictor_train.pos_weight`` (``--pos-weight``; they are ~0.1-1 % of the cells), and augmented by the 8
rotations / flips of the square (the maps live in an arbitrary start frame). Held-out houses (``--val-data``, or
``predictor_train.val_fraction`` of the houses, by house, so no house is in both) give per-category ROC AUC and average
precision over those cells, per directory (one per map type) and overall, beside a geometric baseline
(closer to the explored area = likelier). The optimisation's settings are the ``predictor_train`` config section
(``eval.sections.PredictorTrainConfig``; ``--epochs`` / ``--pos-weight`` / ``--seed`` / ``--val-fraction`` are
shorthands of its keys).

    calnav train-predictor --data runs/maps_ndf runs/maps_rbu runs/maps_glfs --output agent/weights/predictor.pt
"""
from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from calnav.common.atomic import undefined_as_null, write_json_atomic
from calnav.eval.sections import PredictorTrainConfig
from dataclasses import dataclass
from calnav.eval.arguments import REQUIRED, Command, arg
from calnav.eval.config import PREDICTOR_SECTIONS

EXPLORED = 1         # input channel of the explored fraction (agent.prediction.INPUT_CHANNELS)


def auc_ap(scores: np.ndarray, labels: np.ndarray) -> tuple[float, float]:
    """ROC AUC (Mann-Whitney, ties counted half) and average precision (mean precision at each
    positive, ranked by score, ties broken by order) of ``scores`` (N,) for bool ``labels`` (N,).
    NaN for both when labels hold only one class."""
    labels = labels.astype(bool)
    pos, neg = int(labels.sum()), int((~labels).sum())
    if pos == 0 or neg == 0:
        return float("nan"), float("nan")
    order = np.argsort(scores, kind="mergesort")
    s = scores[order]
    ranks = np.empty(len(s))
    # average ranks of tied scores (1-based)
    _, first, counts = np.unique(s, return_index=True, return_counts=True)
    avg = first + (counts + 1) / 2.0
    ranks[order] = np.repeat(avg, counts)
    auc = (ranks[labels].sum() - pos * (pos + 1) / 2.0) / (pos * neg)
    desc = np.argsort(-scores, kind="mergesort")
    hits = labels[desc]
    precision = np.cumsum(hits) / np.arange(1, len(hits) + 1)
    return float(auc), float(precision[hits].mean())


def load_maps(dirs: list[str]) -> tuple[list[dict], dict]:
    """Every episode of the collect-maps directories ``dirs`` as {inputs, targets, scene, source}
    and their common predictor spec dict; ValueError for an empty directory or mixed specs."""
    from calnav.common.npz import load_versioned_npz
    from calnav.eval.prediction.collect import MAPS_FORMAT

    episodes, spec = [], None
    for d in dirs:
        files = sorted((Path(d) / "episodes").glob("*.npz"))
        if not files:
            raise ValueError(f"--data {d}: no collect-maps episodes (episodes/*.npz); run calnav collect-maps first")
        for f in files:
            arrays, meta = load_versioned_npz(f, MAPS_FORMAT)
            if spec is None:
                spec = meta["spec"]
            elif meta["spec"] != spec:
                raise ValueError(f"{f}: collected for another predictor input ({meta['spec']['class_names']}) than "
                                 f"the first file ({spec['class_names']}); train on one kind")
            episodes.append({"inputs": arrays["inputs"], "targets": arrays["targets"], "scene": meta["scene"],
                             "source": str(d)})
    return episodes, spec


def _decision_cells(x, near_cells: int):
    """(B, S, S) bool: unexplored cells within ``near_cells`` (a square) of an explored one --
    where the agent chooses its goals (``PredictorSpec.near_m``)."""
    import torch.nn.functional as F

    explored = x[:, EXPLORED:EXPLORED + 1]
    near = F.max_pool2d((explored > 0).float(), 2 * near_cells + 1, stride=1, padding=near_cells) > 0
    return (near & (explored < 0.5))[:, 0]


def _tensors(episodes: list[dict]):
    import torch

    x = torch.from_numpy(np.concatenate([e["inputs"] for e in episodes])).float().div_(255.0)
    y = torch.from_numpy(np.concatenate([e["targets"] for e in episodes])).float()
    y *= (x[:, EXPLORED:EXPLORED + 1] < 0.5).float()   # PEANUT: the target lies where the input has not looked
    return x, y


def evaluate(net, episodes: list[dict], goals: tuple[str, ...]) -> dict:
    """Per goal category AUC / AP over the cells where the agent chooses (``_decision_cells``)
    of ``episodes``, beside the geometric baseline's, and their means."""
    import torch

    x, y = _tensors(episodes)
    with torch.inference_mode():
        p = torch.cat([torch.sigmoid(net(x[i:i + 64])) for i in range(0, len(x), 64)])
    from scipy.ndimage import distance_transform_edt

    unexplored = _decision_cells(x, int(round(net.spec.near_m / net.spec.cell_m)))
    # the geometric baseline: "goals lie near what has been explored" (minus the distance to the
    # nearest explored cell), which knows no class: what the network adds beyond it is semantics
    near = torch.from_numpy(np.stack([-distance_transform_edt(u) for u in (x[:, EXPLORED] < 0.5).numpy()])
                            .astype(np.float32))
    out = {}
    for g, name in enumerate(goals):
        labels = y[:, g][unexplored].numpy() > 0.5
        auc, ap = auc_ap(p[:, g][unexplored].numpy(), labels)
        base_auc, base_ap = auc_ap(near[unexplored].numpy(), labels)
        out[name] = {"auc": auc, "ap": ap, "positive_rate": float(labels.mean()),
                     "baseline_auc": base_auc, "baseline_ap": base_ap}
    for key in ("auc", "ap", "baseline_auc", "baseline_ap"):
        vals = [out[g][key] for g in goals if np.isfinite(out[g][key])]
        out[f"mean_{key}"] = float(np.mean(vals)) if vals else float("nan")
    return out


def train(episodes: list[dict], spec_dict: dict, cfg: PredictorTrainConfig, progress: bool = True,
          val_episodes: list[dict] | None = None):
    """(net, metrics) -- see the module docstring. ``val_episodes``: held-out maps (other houses);
    None = hold out ``cfg.val_fraction`` of the training houses."""
    import torch
    import torch.nn.functional as F
    from tqdm import tqdm

    from calnav.agent.prediction import PredictorNet, PredictorSpec

    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    scenes = sorted({e["scene"] for e in episodes})
    if val_episodes is None:
        held = set(rng.choice(scenes, size=max(1, int(round(cfg.val_fraction * len(scenes)))), replace=False).tolist())
        train_eps = [e for e in episodes if e["scene"] not in held]
        val_eps = [e for e in episodes if e["scene"] in held]
    else:
        held = {e["scene"] for e in val_episodes}
        if held & set(scenes):
            raise ValueError(f"--val-data shares houses with --data ({', '.join(sorted(held & set(scenes))[:3])}, ...)")
        train_eps, val_eps = episodes, val_episodes
    if not train_eps or not val_eps:
        raise ValueError(f"{len(scenes)} houses cannot be split into training and held-out houses; collect more")
    spec = PredictorSpec.from_dict(spec_dict)
    net = PredictorNet(spec)
    x, y = _tensors(train_eps)
    near_cells = int(round(spec.near_m / spec.cell_m))
    batch = cfg.batch_size
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    weight = torch.full((len(spec.goal_categories), 1, 1), float(cfg.pos_weight))
    steps = cfg.epochs * ((len(x) + batch - 1) // batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=cfg.lr, total_steps=steps, pct_start=0.1)
    history = []
    for epoch in tqdm(range(cfg.epochs), desc="train predictor", unit="epoch", disable=not progress):
        net.train()
        order = torch.from_numpy(rng.permutation(len(x)))
        total = 0.0
        for i in range(0, len(x), batch):
            idx = order[i:i + batch]
            xb, yb = x[idx], y[idx]
            k, flip = int(rng.integers(4)), bool(rng.integers(2))   # one of the square's 8 symmetries
            xb, yb = torch.rot90(xb, k, (2, 3)), torch.rot90(yb, k, (2, 3))
            if flip:
                xb, yb = xb.flip(3), yb.flip(3)
            # the loss where the answer is not obvious: unexplored cells near the explored area (far
            # ones -- mostly outside the house -- are negatives the geometry alone predicts)
            mask = _decision_cells(xb, near_cells).float()[:, None]
            bce = F.binary_cross_entropy_with_logits(net(xb), yb, pos_weight=weight, reduction="none")
            loss = (bce * mask).sum() / (mask.sum() * bce.shape[1]).clamp_min(1.0)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach()) * len(idx)
        history.append(total / len(x))
    net.eval()
    goals = spec.goal_categories
    metrics = {"held_out_houses": sorted(held), "train_snapshots": len(x), "loss": history,
               "val": evaluate(net, val_eps, goals),
               "val_by_source": {s: evaluate(net, [e for e in val_eps if e["source"] == s], goals)
                                 for s in sorted({e["source"] for e in val_eps})}}
    return net, metrics


def train_predictor_configs(args) -> list:
    """The config ``calnav train-predictor`` runs: its ``predictor_train`` section, with
    ``--epochs`` / ``--pos-weight`` / ``--seed`` / ``--val-fraction`` (the command's shorthands)."""
    from calnav.eval.shorthands import load_command_config

    return [load_command_config(args)]


def main_train_predictor(args, configs) -> None:
    """``configs``: ``train_predictor_configs(args)``, checked by the preflight."""
    import sys

    from calnav.agent.prediction import DEFAULT_PREDICTOR, save_predictor
    from calnav.eval.results_dir import check_output_file, writing

    cfg = configs[0].predictor_train
    out = Path(args.output or DEFAULT_PREDICTOR)
    check_output_file(out)
    episodes, spec = load_maps(args.data)
    val_episodes = None
    if args.val_data:
        val_episodes, val_spec = load_maps(args.val_data)
        if val_spec != spec:
            raise ValueError("--val-data was collected for another predictor input than --data")
    t0 = time.perf_counter()
    net, metrics = train(episodes, spec, cfg, val_episodes=val_episodes)
    wall = time.perf_counter() - t0
    meta = {"command": "calnav " + " ".join(sys.argv[1:]), "seed": cfg.seed, "data": list(args.data),
            "pos_weight": cfg.pos_weight, "episodes": len(episodes), "epochs": cfg.epochs,
            "predictor_train": asdict(cfg), "wall_s": round(wall, 1), **metrics}
    with writing(out):
        out.parent.mkdir(parents=True, exist_ok=True)
        save_predictor(net, out, meta)
        write_json_atomic(out.with_suffix(".json"), undefined_as_null(meta), indent=1)
    v = metrics["val"]
    print("held-out houses: " + ", ".join(f"{g} AUC {v[g]['auc']:.3f} AP {v[g]['ap']:.3f}" for g in spec["goal_categories"]))
    print(f"mean AUC {v['mean_auc']:.3f}, mean AP {v['mean_ap']:.3f} (distance-to-explored baseline: AUC "
          f"{v['mean_baseline_auc']:.3f}, AP {v['mean_baseline_ap']:.3f}); {len(episodes)} episodes, "
          f"{wall / 60:.1f} min -> {out}")


@dataclass
class TrainPredictorArgs:
    """``calnav train-predictor``'s flags (the numbers are shorthands of predictor_train keys, whose ranges
    the config checks)."""

    data: list[str] = arg(REQUIRED, "collect-maps directories (mixed)", metavar="DIR")
    output: str | None = arg(None, "weight file (default: agent/weights/predictor.pt)")
    val_data: list[str] | None = arg(None, "collect-maps directories of held-out houses (--split val) for the "
                                           "metrics; default: --val-fraction of the training houses", metavar="DIR")
    val_fraction: float | None = arg(None, "houses held out when there is no --val-data; shorthand for "
                                           "predictor_train.val_fraction (default 0.15)",
                                     sets="predictor_train.val_fraction")
    epochs: int | None = arg(None, "passes over the training maps; shorthand for predictor_train.epochs "
                                   "(default 12)", sets="predictor_train.epochs")
    pos_weight: float | None = arg(None, "BCE weight of goal cells, [1, 1000]; shorthand for "
                                         "predictor_train.pos_weight (default 20; PEANUT's released script 1, its "
                                         "weighted runs inverse frequency): goal cells are ~0.1-1 %% of the "
                                         "unexplored cells", sets="predictor_train.pos_weight")
    seed: int | None = arg(None, "seed of the split, the initialisation and the batches; shorthand for "
                                 "predictor_train.seed (default 0)", sets="predictor_train.seed")


COMMAND = Command(TrainPredictorArgs, main_train_predictor, train_predictor_configs, config="",
                  config_help="YAML config (default: none, the predictor_train defaults)",
                  overrides="dotted config overrides, e.g. predictor_train.lr=5e-4 (before --data, or after "
                            "another option: --data takes every word that follows it)",
                  checks=(),   # trains on collect-maps output: the config names no file or service
                  sections=PREDICTOR_SECTIONS)
