"""Typed configuration of the PEANUT-like ObjectNav agent (YAML section ``agent``).

Every default carries its unit. Cell = one 2D map cell of ``cell_m`` (5 cm, as PEANUT/SemExp).
The parts chosen by name are checked against their registries (``agent.registry``):
``map_type`` (``MAP_BUILDERS``) and ``exploration`` (``GOAL_SELECTORS``). Map type:

- ``fused``: the 3D voxel map (``mapping.fusion`` strategy, calibrated fusion) projected to the
  ground plane: confidence of class l at a cell = mean fused confidence of the surface voxels in
  that cell whose arg-max class is l.
- ``ndf``: the SemExp/PEANUT baseline (no 3D fusion): each frame's per-pixel detections above
  ``ndf_pixel_threshold`` are projected to the ground plane and the 2D map keeps the max over
  time of the per-cell mean pixel confidence.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal

from calnav.agent.registry import DECISIONS, GOAL_CHOICES, GOAL_SELECTORS, MAP_BUILDERS
from calnav.agent.segmenters import check_segmenter_spec
from calnav.common.ranges import Range, check_ranges

METRES = "metres"
MAX_IMAGE_SIDE_PX = 4096   # largest mapping image side, pixels (envs.config.MAX_RESOLUTION_PX, the sensor's)
# The 2D map's side, metres: at least 2 m (one small room around the start), at most 200 m (ten
# times calnav's longest house, ~20 m; the map is centred on the start, so 40 m holds any of
# them). Its memory grows as (map_size_m / cell_m)^2 cells, checked by the preflight.
MAP_SIZE_RANGE = Range(2.0, 200.0, METRES)

# Size-like keys of the agent (``agent``), and why their bounds:
AGENT_RANGES = {
    # a map cell of 1 cm to 0.5 m: finer than the depth noise gains nothing and costs
    # (map_size_m / cell_m)^2 cells of 7 + 12 K bytes (checked against memory by the preflight);
    # coarser than 0.5 m, cells are wider than half a doorway (calnav's are 0.9-1 m), which closes
    "cell_m": Range(0.01, 0.5, METRES),
    "map_size_m": MAP_SIZE_RANGE,
    # heights of the obstacle band, relative to the floor / the camera: within one storey (3 m)
    "obstacle_min_height_m": Range(0.0, 3.0, METRES),
    "obstacle_above_camera_m": Range(0.0, 3.0, METRES),
    "view_block_below_camera_m": Range(0.0, 3.0, METRES),
    # the body the planner dilates obstacles by: as env.agent_radius_m (a 2 cm to 1 m radius)
    "agent_radius_m": Range(0.02, 1.0, METRES),
    # planning distances: within a 10 m room-scale neighbourhood (farther is not "around" the
    # goal / the obstacle), the goal dilation above 0 (else the goal region may be empty)
    "goal_dilation_m": Range(0.0, 10.0, METRES, lo_open=True),
    "clearance_m": Range(0.0, 10.0, METRES),
    "verify_distance_m": Range(0.0, 10.0, METRES),
    "prior_radius_m": Range(0.0, 10.0, METRES),
    # frontier utility and prior bonus: metres of path traded against frontier cells / a related
    # class, within the map's largest side
    "frontier_size_weight_m": Range(0.0, MAP_SIZE_RANGE.hi, METRES),
    "prior_bonus_m": Range(0.0, MAP_SIZE_RANGE.hi, METRES),
    # collision test and marks: a blocked step moves less than 2 m (env.forward_step_m's largest),
    # the marked strip is within 2 m of the agent
    "collision_min_move_m": Range(0.0, 2.0, METRES, lo_open=True),
    "collision_mark_length_m": Range(0.0, 2.0, METRES),
    "collision_mark_width_m": Range(0.0, 2.0, METRES),
    # escape tests: positions within 100 m (the map's half side) of the current one
    "stuck_radius_m": Range(0.0, 100.0, METRES, lo_open=True, hi_open=True),
    "loop_radius_m": Range(0.0, 100.0, METRES, lo_open=True, hi_open=True),
    "prediction_distance_m": Range(0.0, 100.0, METRES, lo_open=True),
    "hole_margin_m": Range(0.0, 2.0, METRES),
    "floor_tolerance_m": Range(0.0, 2.0, METRES),
    # the evidence decision: a second look from within 10 m (room scale, as the planning distances);
    # the bound's z from 0 (the mean alone) to 10 standard errors; views and looks counted
    "evidence_look_distance_m": Range(0.0, 10.0, METRES, lo_open=True),
    "evidence_z": Range(0.0, 10.0, "standard errors"),
    "evidence_min_views": Range(1, 1000, "views"),
    "evidence_confidence": Range(0.0, 1.0, "", lo_open=True, hi_open=True),
    "evidence_looks": Range(0, 10, "looks"),
    "goal_choice_margin": Range(0.0, 1.0, ""),
}

SemanticPrior = Literal["none", "cooccurrence"]


@dataclass
class AgentConfig:
    # --- perception ---------------------------------------------------------------------------
    segmenter: str = "gt"               # gt | noisy | learned_rgb | learned_rgbd | hf | onnx |
                                        # package.module:factory | a calnav.segmenters plugin (agent.segmenters);
                                        # its settings: the top-level segmenter section (SegmenterConfig)
    map_type: str = "fused"             # fused (3D calibrated fusion) | ndf (per-frame 2D max baseline): agent.registry.MAP_BUILDERS
    map_resolution: tuple[int, int] = (160, 120)  # mapping resolution WxH (depth/logits subsampled), pixels
    ndf_pixel_threshold: float = 0.5    # ndf: per-pixel confidence needed to project a detection
    # --- 2D map ---------------------------------------------------------------------------------
    cell_m: float = 0.05                # ground cell edge, metres
    map_size_m: float = 40.0            # square map side centred on the start position, metres
    obstacle_min_height_m: float = 0.25  # points above the floor by at least this are obstacles, metres
    obstacle_above_camera_m: float = 0.01  # ... and below camera height + this, metres
    view_block_below_camera_m: float = 0.1  # obstacle points above camera height - this hide what is behind them (stop line of sight), metres
    agent_radius_m: float = 0.18        # obstacle dilation for traversability, metres
    free_ray_samples: int = 64          # samples per image column when tracing free space
    hole_margin_m: float = 0.0          # floor holes: no depth where the floor should be, this far inside the depth range, metres (0 = off: see docs/scanned_houses.md)
    floor_tolerance_m: float = 0.05     # points this close to the floor height are floor (they clear holes), metres
    # --- goal detection -----------------------------------------------------------------------
    goal_threshold: float = 0.8         # goal-class confidence needed in a cell (PEANUT: 0.985 on
                                        # calibrated segmenter scores; gt at 0.9 fuses to ~0.9)
    goal_min_area_cells: int = 4        # smallest accepted goal component, cells (4 = 0.01 m^2)
    # --- exploration ----------------------------------------------------------------------------
    frontier_min_cells: int = 5         # frontier components smaller than this are ignored, cells
    frontier_size_weight_m: float = 0.02  # utility: -distance + this * frontier cells, metres per cell
    exploration: str = "frontier"       # frontier (frontier size / distance) | prediction (PEANUT's target prediction):
                                        # agent.registry.GOAL_SELECTORS
    predictor_weights: str = ""         # prediction: weight file of calnav train-predictor; "" = agent/weights/predictor.pt
    prediction_distance_m: float = 5.0  # prediction: value = probability x exp(-geodesic distance / this), metres (PEANUT: 500 cm)
    prediction_replan_seen: bool = True  # prediction: re-choose the goal once its cell is explored (PEANUT: at the next call, every replan_steps)
    prediction_no_switch_back: bool = True  # prediction: a periodic re-choice keeps the goal if the new one is the goal it replaced (PEANUT)
    semantic_prior: SemanticPrior = "none"  # none | cooccurrence (frontiers near co-occurring classes)
    prior_bonus_m: float = 2.0          # cooccurrence: distance bonus of a frontier near a related class, metres
    prior_radius_m: float = 1.5         # cooccurrence: "near" means within this, metres
    replan_steps: int = 10              # long-term goal (and the prediction) re-chosen every this many steps (PEANUT: 10)
    # --- local planning -----------------------------------------------------------------------
    goal_dilation_m: float = 0.4        # the long-term goal region is dilated by this, metres
    ring_cells: int = 5                 # short-term goal ring radius around the agent, cells
    clearance_m: float = 0.1            # cells this close to a (dilated) obstacle cost extra, metres
    clearance_cost: float = 4.0         # their traversal cost per cell (free cells cost 1)
    turn_threshold_deg: float = 15.0    # turn when |relative angle| exceeds this, degrees
    stop_margin_m: float = 0.15         # STOP within the task's view-point radius (env.view_point_radius_m) less this of the goal, metres
    blocked_stop_margin_m: float = 0.05  # ... less only this once a forward step toward it was blocked, metres
    stop_view_margin_deg: float = 10.0  # STOP facing the goal within half the field of view less this, degrees
    # --- collisions -----------------------------------------------------------------------------
    collision_min_move_m: float = 0.2   # a forward step travelling less than this is a collision, metres
    collision_mark_length_m: float = 0.3  # obstacle strip marked ahead of a collision, metres
    collision_mark_width_m: float = 0.3   # its width, metres
    untrap_after: int = 4               # blocked forward moves (since the last one that moved) before an escape, moves
    untrap_steps: int = 24              # most actions of one escape (turn + try forward per heading: 2 x 360 / turn angle), actions
    stuck_steps: int = 30               # no progress over this many steps (spin excluded) starts an escape, steps
    stuck_radius_m: float = 0.3         # "no progress": every position of those steps within this of the current one, metres
    loop_steps: int = 120               # going round in circles for this many steps defers the goal it heads for, steps
    loop_radius_m: float = 1.5          # "round in circles": every position of those steps within this, metres
    # --- the task -------------------------------------------------------------------------------
    goal_categories: tuple[str, ...] = ()  # what objectgoal ids name, by id (an episode file's category_to_task_category_id);
                                        # () = calnav's six (HM3D's: chair, bed, plant, toilet, tv_monitor, sofa)
    # --- uncertainty-aware variant (off by default) ---------------------------------------------
    uncertainty_aware: bool = False     # verify uncertain detections before STOP
    uncertain_low: float = 0.3          # goal confidence band [uncertain_low, goal_threshold) counts as a candidate
                                        # (must lie below goal_threshold when uncertainty_aware)
    verify_distance_m: float = 1.0      # approach candidates to this range and re-observe, metres
    # --- the STOP decision (agent.registry.DECISIONS; agent.evidence) ---------------------------
    decision: str = "threshold"         # threshold (STOP on arrival, PEANUT) | evidence (uncertainty test over views first)
    evidence_min_views: int = 3         # evidence: views of the object STOP needs, frames
    evidence_z: float = 1.0             # evidence: STOP needs mean - z * spread / sqrt(views) of the per-view goal
                                        # probability >= evidence_confidence; z in standard errors
    evidence_confidence: float = 0.3    # evidence: ... that lower bound, a probability in (0, 1)
    evidence_looks: int = 1             # evidence: second looks from another bearing before a failing object is rejected, looks
    evidence_look_distance_m: float = 1.5  # evidence: a second look's distance from the object, metres
    # --- which accepted component is the goal (agent.registry.GOAL_CHOICES) ----------------------
    goal_choice: str = "largest"        # largest (PEANUT) | evidence (strongest evidence over views; needs decision: evidence)
    goal_choice_margin: float = 0.1     # evidence: another component replaces the one pursued when its evidence
                                        # lower bound (on the probability scale) is higher by this much, in [0, 1]

    # Left out of saved configs while at these values (``envs.config.plain_dict``): configs saved
    # before the field existed stay equal
    OMIT_AT_DEFAULT: ClassVar[dict[str, Any]] = {"goal_categories": (), "decision": "threshold",
                                                  "evidence_min_views": 3, "evidence_z": 1.0, "evidence_confidence": 0.3, "evidence_looks": 1,
                                                  "evidence_look_distance_m": 1.5, "goal_choice": "largest",
                                                  "goal_choice_margin": 0.1}

    def __post_init__(self) -> None:
        check_segmenter_spec(self.segmenter)   # a misspelt name fails here, importing nothing of it
        MAP_BUILDERS.check(self.map_type)      # names only: the builders load when an agent is built
        GOAL_SELECTORS.check(self.exploration)
        DECISIONS.check(self.decision)
        GOAL_CHOICES.check(self.goal_choice)
        if self.goal_choice == "evidence" and self.decision != "evidence":
            raise ValueError(f"agent.goal_choice=evidence ranks components by the evidence decision's views: it needs "
                             f"agent.decision=evidence, got agent.decision={self.decision}")
        check_ranges(self, "agent", AGENT_RANGES)
        if not self.turn_threshold_deg > 0:
            raise ValueError(f"agent.turn_threshold_deg must be > 0, got {self.turn_threshold_deg}")
        for key in ("goal_threshold", "uncertain_low", "ndf_pixel_threshold"):
            if not 0 <= getattr(self, key) <= 1:
                raise ValueError(f"agent.{key} must be in [0, 1], got {getattr(self, key)}")
        for key in ("ring_cells", "replan_steps", "untrap_after", "untrap_steps", "free_ray_samples", "stuck_steps",
                    "loop_steps", "goal_min_area_cells"):
            if getattr(self, key) < 1:
                raise ValueError(f"agent.{key} must be >= 1, got {getattr(self, key)}")
        for key, hi in (("stop_margin_m", 5.0), ("blocked_stop_margin_m", 5.0), ("stop_view_margin_deg", 90.0)):
            if not 0 <= getattr(self, key) <= hi:   # written so that NaN fails too
                raise ValueError(f"agent.{key} must be in [0, {hi:g}], got {getattr(self, key)}")
        if not self.blocked_stop_margin_m <= self.stop_margin_m:
            raise ValueError(f"agent.blocked_stop_margin_m ({self.blocked_stop_margin_m}) must not exceed "
                             f"agent.stop_margin_m ({self.stop_margin_m}): a blocked step never makes the stop stricter")
        if not self.frontier_min_cells >= 0:
            raise ValueError(f"agent.frontier_min_cells must be >= 0, got {self.frontier_min_cells}")
        if self.uncertainty_aware and not self.uncertain_low < self.goal_threshold:
            raise ValueError(f"agent.uncertain_low ({self.uncertain_low}) must be below agent.goal_threshold "
                             f"({self.goal_threshold}) with agent.uncertainty_aware: the band of candidates to "
                             "verify, [uncertain_low, goal_threshold), would be empty")
        if not self.clearance_cost >= 1:
            raise ValueError(f"agent.clearance_cost must be >= 1 (free cells cost 1), got {self.clearance_cost}")
        names = self.goal_categories
        if not isinstance(names, (tuple, list)) or not all(isinstance(n, str) and n for n in names) \
                or len(set(names)) != len(names):
            raise ValueError(f"agent.goal_categories must be a list of distinct category names (by objectgoal id), "
                             f"got {names!r}")
        w, h = self.map_resolution
        if not (8 <= w <= MAX_IMAGE_SIDE_PX and 8 <= h <= MAX_IMAGE_SIDE_PX):
            raise ValueError(f"agent.map_resolution must be between 8x8 and {MAX_IMAGE_SIDE_PX}x{MAX_IMAGE_SIDE_PX} "
                             f"pixels, got {w}x{h}")

    @property
    def dilation_cells(self) -> float:
        """Obstacle dilation for planning, cells: the agent's radius plus half a cell, as the
        simulator erodes its free floor (``envs.navigation.NavGrid.build``: an obstacle edge lies
        anywhere inside its cell). With the bare radius the planner aims at gaps the simulator
        does not let the agent through (scanned val 0:30, gt: median collisions 8 -> 4)."""
        return (self.agent_radius_m + self.cell_m / 2) / self.cell_m

    @property
    def map_cells(self) -> int:
        """Map side in cells."""
        return int(round(self.map_size_m / self.cell_m))
