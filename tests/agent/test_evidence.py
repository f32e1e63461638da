"""The STOP decision (``agent.evidence``): per-view evidence accounting against hand-computed
cases, the uncertainty test, the second look and the rejection, and the decision as a config key."""
import math

import numpy as np
import pytest

from calnav.agent.approach import Approach
from calnav.agent.config import AgentConfig
from calnav.agent.evidence import BEARING_BINS, Evidence, EvidenceDecision, GoalEvidence, ThresholdDecision
from calnav.agent.goal_detection import GoalDetection
from calnav.agent.semantic_map import MapState
from calnav.envs.task import Action
from calnav.mapping.frame import SegmentedFrame

CELL = 0.1
N = 40                      # map cells a side (4 m)
WIN = (slice(0, N), slice(0, N))


def _state(cfg: AgentConfig) -> MapState:
    st = MapState.empty(np.zeros(2), cfg, 3)
    st.origin = np.array([-2.0, -2.0])       # cell (r, c) centre = (-2 + (c + 0.5) 0.1, -2 + (r + 0.5) 0.1)
    return st


def _cfg(**kw) -> AgentConfig:
    return AgentConfig(cell_m=CELL, map_size_m=N * CELL, decision="evidence", **kw)


def _frame_one_point(x: float, y: float, z: float, goal_logit: float) -> tuple[SegmentedFrame, np.ndarray]:
    """A 1x1 frame whose single pixel sees world point (x, y, z) from a camera at the origin
    (height 0.88 m) looking along +x; logits (goal_logit, 0, 0)."""
    d = float(np.hypot(x, y))
    yaw = math.atan2(y, x)
    # OpenCV camera axes: x right, y down, z forward; world z up
    fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    down = np.array([0.0, 0.0, -1.0])
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, down, fwd], axis=1)
    pose[:3, 3] = (0.0, 0.0, 0.88)
    # pixel (0, 0) at depth d along forward must sit (0.88 - z) below it: y = -cy d / fy
    k = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, -(0.88 - z) / d], [0.0, 0.0, 1.0]])
    frame = SegmentedFrame(depth=np.array([[d]], np.float32), k=k,
                           logits=np.array([[[goal_logit, 0.0, 0.0]]], np.float32), rgb=np.zeros((1, 1, 3), np.uint8))
    return frame, pose


def test_a_view_adds_its_goal_probability_and_bearing_to_the_cell_it_sees():
    cfg = _cfg()
    st = _state(cfg)
    ev = GoalEvidence.empty(N)
    frame, pose = _frame_one_point(1.05, 0.05, 0.5, goal_logit=math.log(2.0))   # softmax: 2 / (2 + 1 + 1) = 0.5
    ev.observe(st, frame, pose, 0, cfg, temperature=1.0)
    r, c = np.argwhere(ev.views).T
    assert (int(r[0]), int(c[0])) == (20, 30) and ev.views.sum() == 1        # x 1.05 -> col 30, y 0.05 -> row 20
    assert ev.q_sum[20, 30] == pytest.approx(0.5) and ev.q_sq[20, 30] == pytest.approx(0.25)
    # seen from the camera at the origin: the object-to-camera bearing is ~180 degrees, sector 4 of 8
    assert ev.bearings[20, 30] == 1 << (BEARING_BINS // 2)
    # a point on the floor (below agent.obstacle_min_height_m) is no view of an object
    floor, pose = _frame_one_point(1.05, 0.05, 0.05, goal_logit=5.0)
    ev.observe(st, floor, pose, 0, cfg, temperature=1.0)
    assert ev.views.sum() == 1
    # a TV on the wall above the 0.88 m camera is a view; the ceiling (above OBJECT_TOP_M) is not
    tv, pose = _frame_one_point(1.05, -0.45, 1.4, goal_logit=0.0)
    ev.observe(st, tv, pose, 0, cfg, temperature=1.0)
    ceiling, pose = _frame_one_point(1.05, -0.95, 2.5, goal_logit=0.0)
    ev.observe(st, ceiling, pose, 0, cfg, temperature=1.0)
    assert ev.views.sum() == 2 and ev.views[15, 30] == 1 and ev.q_sum[15, 30] == pytest.approx(1 / 3)
    # temperature 2 halves the logit: softmax (sqrt 2, 1, 1) -> 0.4142
    frame, pose = _frame_one_point(1.05, 0.05, 0.5, goal_logit=math.log(2.0))
    ev.observe(st, frame, pose, 0, cfg, temperature=2.0)
    q2 = math.sqrt(2) / (math.sqrt(2) + 2)
    assert ev.views[20, 30] == 2 and ev.q_sum[20, 30] == pytest.approx(0.5 + q2)


def test_a_components_evidence_pools_its_cells_views():
    """Two cells: views 3 (q 0.9, 0.9, 0.6) and 1 (q 0.3): n = 3, mean = 2.7 / 4 = 0.675,
    spread = sqrt((0.81 + 0.81 + 0.36 + 0.09) / 4 - 0.675^2) = sqrt(0.061875)."""
    ev = GoalEvidence.empty(N)
    ev.views[5, 5], ev.q_sum[5, 5], ev.q_sq[5, 5], ev.bearings[5, 5] = 3, 2.4, 0.81 + 0.81 + 0.36, 0b001
    ev.views[5, 6], ev.q_sum[5, 6], ev.q_sq[5, 6], ev.bearings[5, 6] = 1, 0.3, 0.09, 0b100
    mask = np.zeros((N, N), bool)
    mask[5, 5:7] = True
    conf = np.zeros((N, N), np.float32)
    conf[5, 5], conf[5, 6] = 0.99, 0.97
    e = ev.of(mask, conf, WIN)
    assert (e.n, e.bearings) == (3, 0b101)
    assert e.p == pytest.approx(0.98) and e.mean == pytest.approx(0.675)
    assert e.spread == pytest.approx(math.sqrt(0.061875))
    assert e.lower_bound(2.0) == pytest.approx(0.675 - 2 * math.sqrt(0.061875) / math.sqrt(3))
    assert Evidence(0.9, 0, 0.0, 0.0, 0).lower_bound(1.0) == -math.inf


def _decision(**kw) -> tuple[EvidenceDecision, MapState, np.ndarray]:
    cfg = _cfg(**kw)
    st = _state(cfg)
    st.channels[1] = True      # all explored and free: every cell traversable
    dec = EvidenceDecision(cfg, temperature=1.0)
    dec.reset(N)
    goal = np.zeros((N, N), bool)
    goal[20:22, 20:22] = True
    return dec, st, goal


def _views(dec: EvidenceDecision, goal: np.ndarray, n: int, q: float, sector: int) -> None:
    ev = dec.evidence
    ev.views[goal] = n
    ev.q_sum[goal] = n * q
    ev.q_sq[goal] = n * q * q
    ev.bearings[goal] = 1 << sector


def test_stop_passes_on_consistent_views_and_looks_again_then_rejects_on_weak_ones():
    dec, st, goal = _decision(evidence_min_views=3, evidence_z=1.0, evidence_confidence=0.5, evidence_looks=1,
                              evidence_look_distance_m=1.0)
    free = np.ones((N, N), bool)
    det = GoalDetection(True, goal, int(goal.sum()), 0.99)
    stop = Approach("stop", (20, 20), action=int(Action.STOP))
    agent = (20, 12)                                   # west of the object: sector 4 (object -> camera)
    _views(dec, goal, 5, 0.9, sector=4)
    assert dec.review(stop, det, st, 0, WIN, agent, free) is stop          # lower bound 0.9 >= 0.5
    _views(dec, goal, 2, 0.9, sector=4)
    look = dec.review(stop, det, st, 0, WIN, agent, free)                 # too few views: a second look
    assert look.mode == "look" and look.target.sum() == 1
    (r, c), = np.argwhere(look.target)
    away = math.degrees(math.atan2(r - 20.5, c - 20.5)) % 360
    assert not 180 <= away < 225, away                                   # not from the sector already seen
    assert 5 <= math.dist((r, c), (20.5, 20.5)) <= 21
    # on the way there, the look goes on whatever the approach says
    assert dec.review(Approach("goal", (20, 20), target=goal), det, st, 0, WIN, agent, free).mode == "look"
    # arrived, the views still weak (mean 0.3): the last look is spent, the object is rejected
    _views(dec, goal, 6, 0.3, sector=2)
    assert dec.review(stop, det, st, 0, WIN, (int(r), int(c)), free).mode == "reject"


def test_an_unreachable_look_is_given_up():
    dec, st, goal = _decision(evidence_min_views=3)
    free = np.ones((N, N), bool)
    det = GoalDetection(True, goal, int(goal.sum()), 0.99)
    _views(dec, goal, 1, 0.9, sector=4)
    assert dec.review(Approach("stop", (20, 20), action=int(Action.STOP)), det, st, 0, WIN, (20, 12), free).mode == "look"
    dec.abandon()
    assert dec.target is None
    assert dec.review(Approach("stop", (20, 20), action=int(Action.STOP)), det, st, 0, WIN, (20, 12), free).mode == "reject"


def test_threshold_decision_passes_every_move_through():
    cfg = AgentConfig()
    dec = ThresholdDecision(cfg, 1.0)
    move = Approach("stop", (0, 0), action=int(Action.STOP))
    assert dec.review(move, None, None, 0, WIN, (0, 0), None) is move


def test_the_decision_is_a_config_key_with_declared_ranges():
    from calnav.eval.config import ConfigError, load_config

    assert load_config(None, ["agent.decision=evidence"]).agent.decision == "evidence"
    with pytest.raises(ConfigError, match="unknown decision 'evidnce' for agent.decision; valid choices: threshold, evidence"):
        load_config(None, ["agent.decision=evidnce"])
    with pytest.raises(ConfigError, match="bad value for agent.evidence_z: 'nan'; expected a finite number"):
        load_config(None, ["agent.evidence_z=nan"])
    for key, bad in (("evidence_z", "11"), ("evidence_confidence", "1"), ("evidence_min_views", "0"),
                     ("evidence_look_distance_m", "0"), ("evidence_looks", "-1")):
        with pytest.raises(ConfigError, match=f"agent.{key} must be in"):
            load_config(None, [f"agent.{key}={bad}"])
    # at their defaults the keys are left out of saved configs: older records keep their config
    from calnav.envs.config import plain_dict

    saved = plain_dict(AgentConfig())
    assert not any(k.startswith("evidence") or k == "decision" for k in saved)
    assert plain_dict(AgentConfig(decision="evidence"))["decision"] == "evidence"
