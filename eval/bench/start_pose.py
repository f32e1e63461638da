"""Bench section "start_pose": is the PEANUT agent equally good whatever its start pose?

The agent (learned_rgb segmenter, GLFS fusion with the shipped parameters, goal threshold
GOAL_THRESHOLD as tuned for it, 160x120) runs the first EPISODES ``val`` episodes (QUICK_EPISODES
with ``--quick``) under each frame variant of ``eval.objectnav.start_pose.DEFAULT_VARIANTS``: the
old world frame, Habitat's start frame, the start frame shifted by less than a cell, a rotated
and shifted frame, and houses rotated by 37 degrees. Figures:

- ``start_pose.success_<variant>``: Success (fraction of the episodes).
- ``start_pose.max_success_gap``: the largest Success difference between two variants.

The same study at any size: ``calnav start-pose`` (``eval.objectnav.start_pose``).
"""
from __future__ import annotations

EPISODES = 8            # 8 episodes x 5 variants = 40 episodes, ~4 min on 2 free cores
QUICK_EPISODES = 2
GOAL_THRESHOLD = 0.7    # `calnav tune`'s pick for learned_rgb + GLFS (docs/objectnav_study.md, start-pose study)
OVERRIDES = ["env.resolution=160x120", "agent.segmenter=learned_rgb", "mapping.fusion=glfs",
             "mapping.glfs_params=agent/weights/glfs_learned_rgb.json", f"agent.goal_threshold={GOAL_THRESHOLD}"]


def run(ctx) -> dict[str, float]:
    from calnav.eval.config import load_config
    from calnav.eval.objectnav.start_pose import DEFAULT_VARIANTS, VARIANTS, run_start_pose_study

    cfg = load_config(None, [*OVERRIDES, "run.workers=2"])
    n = QUICK_EPISODES if ctx.quick else EPISODES
    summary = run_start_pose_study(cfg, list(range(n)), [VARIANTS[v] for v in DEFAULT_VARIANTS], out=None,
                              progress=False)
    success = {name: s["success"] for name, s in summary.items()}
    return {**{f"start_pose.success_{k}": v for k, v in success.items()},
            "start_pose.max_success_gap": max(success.values()) - min(success.values())}
