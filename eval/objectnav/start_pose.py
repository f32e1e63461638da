"""Start-pose study: is the agent equally good whatever frame its poses come in and whatever
the house's orientation? (The agent maps in the episode-start frame that Habitat's
gps + compass give, so nothing may depend on where that frame's origin and axes fall.)

A ``PoseVariant`` names how the agent's gps + compass are expressed and how the house lies:

- ``base``: ``start`` (Habitat's: origin at the start, x along the start heading) or
  ``world`` (the simulator's world frame: the old privileged protocol's poses);
- then the frame is rotated by ``yaw_deg`` and its origin shifted by ``offset_m`` (x, y):
  the agent sees gps / compass of the pose ``R(yaw) p + offset`` (a rigid change of frame,
  so the episode itself is unchanged);
- ``house_yaw_deg``: the house mesh, the start poses and the goals are rotated about the
  world origin (walls no longer axis-aligned in the world; ``rotated_setup``).

``reexpress_obs`` does the change of frame on one observation; ``PoseVariantWrapper`` applies it in a
gymnasium env; ``run_start_pose_study`` runs episodes x variants through the episode runner every
ObjectNav command uses (``eval.objectnav.run.run_jobs``: the ``run.backend`` backend, one
resumable results directory per variant with its ``episodes.jsonl`` and ``summary.json``) and
writes ``summary.json`` / ``summary.csv`` (Success as successes / N and mean SPL per variant) /
``summary.png`` beside them; ``lockstep_map_stats`` drives one
episode with the first variant's actions and records every variant's map statistics per step
(the instrument that found the sensitive stage).
"""
from __future__ import annotations

import csv
import io
import json
import math
import tempfile
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from calnav.eval.arguments import Command, arg

POSE_BASES = ("start", "world")


@dataclass(frozen=True)
class PoseVariant:
    """How the agent's poses are expressed (see module docstring). offset_m (x, y) metres;
    yaw_deg / house_yaw_deg degrees, counter-clockwise."""

    name: str
    base: str = "start"
    offset_m: tuple[float, float] = (0.0, 0.0)
    yaw_deg: float = 0.0
    house_yaw_deg: float = 0.0

    def __post_init__(self) -> None:
        if self.base not in POSE_BASES:
            raise ValueError(f"unknown frame base {self.base!r}; valid: {', '.join(POSE_BASES)}")


# The study's variants, by name (``calnav start-pose --variants``). Offsets and yaws are
# arbitrary values, none a multiple of the 5 cm cell or of 90 degrees.
VARIANTS: dict[str, PoseVariant] = {v.name: v for v in (
    PoseVariant("world", "world"),                                      # the old privileged protocol's frame
    PoseVariant("start"),                                               # Habitat's gps + compass
    PoseVariant("start_offset", offset_m=(0.013, 0.027)),               # origin shifted by less than a cell
    PoseVariant("start_offset_far", offset_m=(100.013, -100.013)),      # origin 141 m away
    PoseVariant("start_rotated", offset_m=(3.217, -1.709), yaw_deg=23.0),  # a rotated, shifted frame
    PoseVariant("world_offset_far", "world", offset_m=(100.013, -100.013)),
    PoseVariant("house_yaw37", house_yaw_deg=37.0),                     # houses rotated: walls off the axes
    PoseVariant("house_yaw118", house_yaw_deg=118.0),
)}
DEFAULT_VARIANTS = ("world", "start", "start_offset", "start_rotated", "house_yaw37")


def parse_variants(spec: str) -> list[PoseVariant]:
    """Comma-separated variant names -> variants (a clear error names the valid ones)."""
    names = [n for n in spec.split(",") if n]
    unknown = [n for n in names if n not in VARIANTS]
    if unknown or not names:
        raise ValueError(f"unknown start-pose variant {unknown[0] if unknown else spec!r}; valid: {', '.join(VARIANTS)}")
    return [VARIANTS[n] for n in dict.fromkeys(names)]


def rot2(theta: float) -> np.ndarray:
    """(2, 2) counter-clockwise rotation by theta rad."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def reexpress_obs(obs: dict, variant: PoseVariant, start_xy, start_yaw: float) -> dict:
    """A copy of ``obs`` whose gps / compass express the agent's pose in ``variant``'s frame.
    start_xy (2,) metres / start_yaw rad: the episode's world start pose (for base ``world``)."""
    from calnav.envs.task import COMPASS, GPS, gps_compass_to_xy_yaw, wrap_angle

    xy, yaw = gps_compass_to_xy_yaw(obs[GPS], obs[COMPASS])
    if variant.base == "world":
        xy, yaw = np.asarray(start_xy, np.float64) + rot2(start_yaw) @ xy, yaw + start_yaw
    theta = math.radians(variant.yaw_deg)
    xy = rot2(theta) @ xy + np.asarray(variant.offset_m, np.float64)
    out = dict(obs)
    out[GPS] = np.array([xy[0], -xy[1]], np.float32)
    out[COMPASS] = np.array([wrap_angle(yaw + theta)], np.float32)
    return out


def _variant_wrapper_class():
    import gymnasium as gym

    class PoseVariantWrapper(gym.ObservationWrapper):
        """Expresses gps / compass in a ``PoseVariant``'s frame (the episode is unchanged)."""

        def __init__(self, env, variant: PoseVariant):
            super().__init__(env)
            self.variant = variant

        def observation(self, obs):
            ep = self.env.unwrapped.episode
            return reexpress_obs(obs, self.variant, ep.start_position, ep.start_yaw)

    return PoseVariantWrapper


def rotate_scene(scene, yaw_rad: float):
    """The scene rotated by yaw_rad about the world z axis (through x = y = 0). Its axis-aligned
    ``rooms`` no longer describe it and are dropped."""
    r = np.eye(3)
    r[:2, :2] = rot2(yaw_rad)
    v = (np.asarray(scene.vertices, np.float64) @ r.T).astype(np.float32)
    return replace(scene, vertices=v, rooms=[], meta={**scene.meta, "rotated_deg": math.degrees(yaw_rad)})


def rotate_episode(ep, yaw_rad: float):
    """The episode with its start pose and goals rotated like ``rotate_scene``."""
    from calnav.envs.task import yaw_to_habitat_quaternion

    r2 = rot2(yaw_rad)
    r3 = np.eye(3)
    r3[:2, :2] = r2
    goals = [replace(g, position=r3 @ np.asarray(g.position, np.float64),
                     view_points=np.asarray(g.view_points, np.float64) @ r2.T) for g in ep.goals]
    return replace(ep, start_position=r2 @ np.asarray(ep.start_position, np.float64),
                   start_rotation=yaw_to_habitat_quaternion((ep.start_yaw + yaw_rad) % (2 * math.pi)), goals=goals)


def rotated_setup(env_cfg, episodes: list, yaw_deg: float, scene_dir: Path):
    """(env config reading the rotated houses from ``scene_dir``, rotated episodes): every
    scene of ``episodes`` is rotated by yaw_deg and saved as ``scene_dir/<scene_id>.npz``."""
    from calnav.envs.scenes import load_scene

    yaw = math.radians(yaw_deg)
    scene_dir.mkdir(parents=True, exist_ok=True)
    for sid in sorted({ep.scene_id for ep in episodes}):
        path = scene_dir / f"{sid}.npz"
        if not path.exists():
            rotate_scene(load_scene(sid, env_cfg.dataset), yaw).save(path)
    cfg = replace(env_cfg, dataset=replace(env_cfg.dataset, scene_dir=str(scene_dir)))
    return cfg, [rotate_episode(ep, yaw) for ep in episodes]


def make_env(cfg, variant: PoseVariant, work_dir: Path, upto: int | None = None):
    """The gym env of ``cfg.env``'s split for ``variant`` (rotated houses under work_dir);
    ``upto``: the episodes ``0:upto`` are enough (``envs.episodes.load_split``)."""
    import gymnasium as gym

    import calnav.envs  # noqa: F401  (registers the env)
    from calnav.envs.episodes import load_split

    env_cfg, episodes = cfg.env, load_split(cfg.env.split, cfg.env, progress=False, upto=upto)
    if variant.house_yaw_deg:
        env_cfg, episodes = rotated_setup(env_cfg, episodes, variant.house_yaw_deg,
                                          work_dir / f"houses_{variant.house_yaw_deg:g}deg")
    env = gym.make("calnav/ObjectNav-v0", split=env_cfg.split, config=env_cfg, episodes=episodes)
    return _variant_wrapper_class()(env, variant)


# ---------------------------------------------------------------------------- episodes x variants
STUDY_RESULTS = ("episodes.jsonl", "summary.json", "summary.csv", "summary.png")  # what --force discards
VARIANT_ENV = "calnav.eval.objectnav.start_pose:variant_env"   # the episode runner's env maker for a variant


def variant_env(cfg, variant: dict, work_dir: str, upto: int | None = None):
    """``make_env`` for the episode runner (``eval.objectnav.run``): the variant as a plain dict
    (picklable for any backend)."""
    return make_env(cfg, PoseVariant(**{**variant, "offset_m": tuple(variant["offset_m"])}), Path(work_dir), upto)


def _claim_variant_dir(path: Path, variant: PoseVariant, force: bool) -> None:
    """Write the variant's definition beside its records (``variant.json``); a directory holding
    another definition of the same name (``VARIANTS`` edited) is refused, or with ``force`` its
    records are discarded: the run config alone does not say which frame they were run in."""
    from calnav.common.atomic import write_json_atomic
    from calnav.eval.results_dir import RECORDS_NAME, ResultsError, writing

    want = json.loads(json.dumps(asdict(variant)))
    marker = path / "variant.json"
    if marker.is_file():
        have = json.loads(marker.read_text())
        if have != want:
            if not force:
                raise ResultsError(f"{path} holds episodes of another definition of variant {variant.name!r} "
                                   f"({have}, now {want}); pass --force to discard them")
            for name in (RECORDS_NAME, "summary.json"):
                (path / name).unlink(missing_ok=True)
    with writing(marker):
        path.mkdir(parents=True, exist_ok=True)
        write_json_atomic(marker, want)


def run_start_pose_study(cfg, indices: list[int], variants: list[PoseVariant], out: Path | None,
                    progress: bool = True, force: bool = False) -> dict[str, dict]:
    """Run every (variant, episode) with the PEANUT agent of ``cfg`` through the episode runner
    (``eval.objectnav.run.run_jobs``: the ``run.backend`` backend, resumable records, crashed
    episodes recorded and retried, the shared summary); one results directory per variant,
    ``<out>/<variant>/`` (``episodes.jsonl``, ``summary.json``), under ``out`` (locked, config
    checked: a different config is refused unless ``force``), which gets ``summary.json`` /
    ``summary.csv`` / ``summary.png``. Returns variant name -> {success, successes, spl, n,
    success_sem, spl_sem, variant fields}. ``out`` None: a temporary directory."""
    from contextlib import ExitStack

    from calnav.envs.episodes import load_split
    from calnav.eval.objectnav.run import EpisodeJob, run_jobs
    from calnav.eval.results_dir import ResultsDir, writing

    names, upto = [v.name for v in variants], max(indices) + 1
    if len(set(names)) != len(names):
        raise ValueError(f"frame variants need distinct names, got {names}")
    with ExitStack() as stack:
        results = stack.enter_context(ResultsDir(out, cfg, force=force, discard=STUDY_RESULTS)) if out else None
        work = Path(out) if out else Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="calnav_start_pose_")))
        for v in variants:   # write rotated houses once, before the workers start
            if v.house_yaw_deg:
                rotated_setup(cfg.env, load_split(cfg.env.split, cfg.env, progress=False, upto=upto), v.house_yaw_deg,
                              work / f"houses_{v.house_yaw_deg:g}deg")
        for v in variants:   # a variant's directory holds that definition's episodes only
            _claim_variant_dir(work / v.name, v, force)
        jobs = [EpisodeJob(cfg, list(indices), work / v.name, env_maker=VARIANT_ENV,
                           env_args={"variant": asdict(v), "work_dir": str(work), "upto": upto}) for v in variants]
        summaries = run_jobs(jobs, force=force, progress=progress, plots=False)
        summary = {v.name: {"success": s["success"], "successes": int(round(s["success"] * s["count"])),
                            "spl": s["spl"], "n": s["count"], "success_sem": s["success_sem"],
                            "spl_sem": s["spl_sem"], "failed": s["failed"], **asdict(v)}
                   for v, s in zip(variants, summaries)}
        if results is not None:
            results.write_json("summary.json", summary)
            buf = io.StringIO(newline="")
            w = csv.writer(buf)
            w.writerow(["variant", "successes", "n", "success", "spl"])
            for name, s in summary.items():
                w.writerow([name, s["successes"], s["n"], f"{s['success']:.3f}", f"{s['spl']:.3f}"])
            results.write_text("summary.csv", buf.getvalue())
            with writing(Path(out) / "summary.png"):
                plot_summary(summary, Path(out) / "summary.png")
    return summary


def plot_summary(summary: dict[str, dict], path: Path) -> None:
    """Bar plot of Success and SPL per variant (summary from ``run_start_pose_study``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(summary)
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(1.2 * len(names) + 2, 3.5))
    ax.bar(x - 0.2, [summary[n]["success"] for n in names], 0.4, label="Success")
    ax.bar(x + 0.2, [summary[n]["spl"] for n in names], 0.4, label="SPL")
    ax.set_xticks(x, names, rotation=30, ha="right")
    ax.set_ylim(0, 1)
    ax.set_title(f"start-pose study, {summary[names[0]]['n']} episodes per variant")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# ---------------------------------------------------------------------------- the instrument
def map_stats(step, goal_threshold: float) -> dict[str, float]:
    """Frame-independent statistics of an agent's maps after a step (``agent.step.Step``): cell
    counts of each 2D channel, of goal-class cells with any vote and above ``goal_threshold``,
    the detected goal component's area, and the decision mode."""
    from calnav.agent.semantic_map import MapChannels

    st, info = step.state, step.info
    goal = st.semantic[step.goal_channel]
    det = info.detection if info is not None else None
    return {**{f"{c.name.lower()}_cells": int(st.channels[c].sum()) for c in MapChannels},
            "goal_cells": int((goal > 0).sum()), "goal_above_threshold": int((goal >= goal_threshold).sum()),
            "semantic_cells": int((st.counts.sum(axis=0) > 0).sum()),
            "goal_area": int(det.area) if det is not None and det.found else 0,
            "mode": info.mode if info is not None else ""}


class Lockstep:
    """Several PeanutAgents driven as one (an ``eval.rollout`` agent): each sees the same frames
    re-expressed in its variant's gps / compass frame and maps them; the first one's action is
    sent. ``rows``: one per step and variant, {step, variant, action, **map_stats}."""

    def __init__(self, cfg, env, variants: list[PoseVariant]):
        from calnav.agent.policy import PeanutAgent
        from calnav.eval.config import agent_setup

        self.env, self.variants, self.goal_threshold = env, variants, cfg.agent.goal_threshold
        self.agents = [PeanutAgent(agent_setup(cfg, "peanut")) for _ in variants]
        self.rows: list[dict] = []

    def _views(self, obs: dict) -> list[dict]:
        ep = self.env.episode
        return [reexpress_obs(obs, v, ep.start_position, ep.start_yaw) for v in self.variants]

    def reset(self, obs: dict) -> None:
        for agent, view in zip(self.agents, self._views(obs)):
            agent.reset(view)
        self.rows = []

    def act(self, obs: dict):
        """The first variant's ``agent.step.Step``."""
        n = len(self.rows) // len(self.agents)
        steps = [a.act(view) for a, view in zip(self.agents, self._views(obs))]
        self.rows += [{"step": n, "variant": v.name, "action": s.action, **map_stats(s, self.goal_threshold)}
                      for v, s in zip(self.variants, steps)]
        return steps[0]


def lockstep_map_stats(cfg, index: int, variants: list[PoseVariant], steps: int) -> list[dict]:
    """Drive episode ``index`` with the first variant's agent for up to ``steps`` steps; every
    variant's agent sees the same frames (its own gps / compass frame) and maps them
    (``Lockstep``). Returns one row per step and variant: {step, variant, action, **map_stats}.
    House rotations are not supported here (they change the frames themselves)."""
    import gymnasium as gym

    import calnav.envs  # noqa: F401
    from calnav.eval.rollout import rollout

    if any(v.house_yaw_deg for v in variants):
        raise ValueError("lockstep_map_stats compares frames of one house: house_yaw_deg must be 0")
    env = gym.make("calnav/ObjectNav-v0", split=cfg.env.split, config=cfg.env).unwrapped
    lockstep = Lockstep(cfg, env, variants)
    rollout(env, lockstep, index, max_steps=steps)
    return lockstep.rows


def start_pose_configs(args) -> list:
    """The config ``calnav start-pose`` runs (``--workers N`` as ``run.workers=N`` only when given:
    it never silently replaces the config's)."""
    from calnav.eval.shorthands import load_command_config

    parse_variants(args.variants)           # every check before anything runs
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    cfg = load_command_config(args)
    if cfg.run.agent != "peanut":
        raise ValueError(f"start-pose runs the peanut agent (its maps live in the start frame), got run.agent={cfg.run.agent}")
    return [cfg]


def main_start_pose(args, configs) -> None:
    """`calnav start-pose`: the PEANUT agent on ``--episodes`` under each ``--variants`` frame.
    ``configs``: ``start_pose_configs(args)``, checked by the preflight."""
    from calnav.eval.episodes import episode_indices

    variants = parse_variants(args.variants)
    cfg = configs[0]
    indices = episode_indices(str(args.episodes), cfg.env, cfg.run)
    out = Path(args.output)
    summary = run_start_pose_study(cfg, indices, variants, out, force=args.force)
    print("| variant | Success | SPL | N |\n|---|---|---|---|")
    for name, s in summary.items():
        print(f"| {name} | {s['successes']}/{s['n']} | {s['spl']:.3f} | {s['n']} |")
    print(f"results: {out}/summary.json, {out}/summary.csv, {out}/episodes.jsonl")


@dataclass
class StartPoseArgs:
    """``calnav start-pose``'s flags."""

    episodes: str = arg("0:14", "N (first N) or A:B (a range) of the split's episodes")
    variants: str = arg("world,start,start_offset,start_rotated,house_yaw37",
                        "comma-separated variants (eval.objectnav.start_pose.VARIANTS)")
    workers: int | None = arg(None, "worker processes (shorthand for run.workers; default: the config's)",
                              sets="run.workers")
    output: str = arg("runs/start_pose", "results directory")
    force: bool = arg(False, "discard results of a different config in --output")


COMMAND = Command(StartPoseArgs, main_start_pose, start_pose_configs, config="configs/objectnav.yaml")
