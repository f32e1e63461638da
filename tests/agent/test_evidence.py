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


def test_looks_are_counted_per_object_when_the_largest_component_changes():
    """goal_choice=largest: a second look at A is under way when B becomes the largest, and the
    approach heads for B. The look for A is dropped; B, failing its test on arrival, gets a
    second look of its own (not a rejection on A's look); A, back as the goal, has spent its
    look and is rejected when it fails again."""
    dec, st, a = _decision(evidence_min_views=3, evidence_looks=1, evidence_look_distance_m=1.0)
    b = np.zeros((N, N), bool)
    b[8:10, 30:32] = True
    free = np.ones((N, N), bool)
    _views(dec, a, 1, 0.9, sector=4)
    _views(dec, b, 1, 0.9, sector=4)
    det_a, det_b = GoalDetection(True, a, 4, 0.99), GoalDetection(True, b, 4, 0.99)
    stop_a = Approach("stop", (20, 20), action=int(Action.STOP))
    stop_b = Approach("stop", (8, 30), action=int(Action.STOP))
    assert dec.review(stop_a, det_a, st, 0, WIN, (20, 12), free).mode == "look" and dec.looking
    to_b = Approach("goal", (8, 30), target=b)
    assert dec.review(to_b, det_b, st, 0, WIN, (20, 12), free) is to_b and not dec.looking
    look = dec.review(stop_b, det_b, st, 0, WIN, (8, 22), free)
    assert look.mode == "look" and (dec.looks(b, WIN), dec.looks(a, WIN)) == (1, 1)
    (r, c), = np.argwhere(look.target)
    assert 5 <= math.dist((r, c), (8.5, 30.5)) <= 11
    dec.abandon()
    assert dec.review(stop_a, det_a, st, 0, WIN, (20, 12), free).mode == "reject"
    assert dec.review(stop_b, det_b, st, 0, WIN, (8, 22), free).mode == "reject"


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


def _two_objects(cfg: AgentConfig, win=WIN):
    """A big component A (5x5 cells) no view saw at object heights and a small one B (3x3) with
    4 views of goal probability 0.8 at every cell, in window ``win`` of the map; their
    confidence there (0.9 on both), and the evidence decision holding those views."""
    h, w = win[0].stop - win[0].start, win[1].stop - win[1].start
    conf = np.zeros((h, w))
    a = np.zeros((h, w), bool)
    a[5:10, 5:10] = True
    b = np.zeros((h, w), bool)
    b[20:23, 25:28] = True
    conf[a | b] = 0.9
    dec = EvidenceDecision(cfg, 1.0)
    dec.reset(N)
    ev = dec.evidence
    full_b = np.zeros((N, N), bool)
    full_b[win] = b
    ev.views[full_b], ev.q_sum[full_b], ev.q_sq[full_b] = 4, 4 * 0.8, 4 * 0.8 ** 2
    return conf, a, b, dec


def test_the_evidence_goal_choice_takes_the_object_the_views_support_not_the_largest():
    """Two components above the threshold: PEANUT's rule takes the larger, one seen only on the
    floor (no views: no lower bound); agent.goal_choice=evidence takes the smaller one whose 4
    views say 0.8 (it passes the STOP test: lower bound 0.8 - 1 * 0 / 2 >= 0.3) -- also in a
    planning window that is not the whole map, where the views sit at the map's own cells."""
    from calnav.agent.goal_detection import GoalDetector

    cfg = _cfg(goal_threshold=0.5, goal_min_area_cells=4)
    for win in (WIN, (slice(3, 33), slice(2, 38))):
        conf, a, b, dec = _two_objects(cfg, win)
        largest, _ = GoalDetector(dataclasses_replace(cfg, goal_choice="largest"), N).detect(conf, win, dec)
        detector = GoalDetector(dataclasses_replace(cfg, goal_choice="evidence"), N)
        by_evidence, _ = detector.detect(conf, win, dec)
        assert largest.found and (largest.mask == a).all() and largest.area == 25
        assert by_evidence.found and (by_evidence.mask == b).all() and by_evidence.area == 9
        assert (detector.choice.pursued[win] == b).all() and detector.choice.pursued.sum() == 9
    # without views on either, the evidence choice falls back to the larger
    dec.reset(N)
    det, _ = GoalDetector(dataclasses_replace(cfg, goal_choice="evidence"), N).detect(conf, win, dec)
    assert (det.mask == a).all()


def test_the_evidence_goal_choice_keeps_the_pursued_object_within_the_margin():
    """Both components seen, neither passing the STOP test (2 views < 3): the goal pursued stays
    the goal while the other's lower bound is within goal_choice_margin (0.1) above it, and
    changes when it is more than that above, or when the other passes the test (a tier up);
    each object keeps its own looks across the changes."""
    from calnav.agent.evidence import EvidenceChoice

    cfg = _cfg(goal_threshold=0.5, goal_min_area_cells=4, goal_choice="evidence", goal_choice_margin=0.1)
    conf, a, b, dec = _two_objects(cfg)
    ev = dec.evidence

    def seen(mask, views, q):
        ev.views[mask], ev.q_sum[mask], ev.q_sq[mask] = views, views * q, views * q * q

    choice = EvidenceChoice(cfg, N)
    seen(a, 2, 0.6), seen(b, 2, 0.5)
    masks, areas = [a, b], [25, 9]
    assert choice.picker(conf, WIN, dec)(masks, areas) == 0 and (choice.pursued == a).all()
    seen(b, 2, 0.68)                                      # 0.68 - 0.6 = 0.08 <= 0.1: keep A
    assert choice.picker(conf, WIN, dec)(masks, areas) == 0
    dec.looked[a] = 1                                     # a look was taken at A
    seen(b, 2, 0.75)                                      # 0.15 above: B, with no looks taken at it
    assert choice.picker(conf, WIN, dec)(masks, areas) == 1 and (choice.pursued == b).all()
    assert (dec.looks(b, WIN), dec.looks(a, WIN)) == (0, 1)
    seen(a, 2, 0.8)                                       # A 0.05 above B, within the margin: B stays
    assert choice.picker(conf, WIN, dec)(masks, areas) == 1
    seen(a, 3, 0.62)                                      # A passes the test (3 views), B does not: A ...
    dec.target, dec.look_for[b] = (0, 0), True            # ... but not while a look at B is under way
    assert choice.picker(conf, WIN, dec)(masks, areas) == 1
    dec.target = None
    assert choice.picker(conf, WIN, dec)(masks, areas) == 0 and dec.looks(a, WIN) == 1   # A kept its look
    with pytest.raises(ValueError, match="needs the evidence decision's views"):
        choice.picker(conf, WIN, ThresholdDecision(cfg, 1.0))


def test_components_are_listed_largest_first_above_the_minimum_area():
    from calnav.agent.goal_detection import components, largest_component

    m = np.zeros((8, 8), bool)
    m[0, 0:3] = True            # 3 cells
    m[4:6, 4:7] = True          # 6 cells
    m[7, 0] = True              # 1 cell
    m[0, 6], m[1, 7] = True, True   # 2 cells touching at a corner: one component (8-connected)
    masks, areas = components(m, 2)
    assert areas == [6, 3, 2] and masks[0].sum() == 6 and masks[2][0, 6] and masks[2][1, 7]
    assert not any(mk[7, 0] for mk in masks)
    assert components(m, 2, most=1)[1] == [6] and components(m, 7) == ([], [])
    mask, area = largest_component(m, 2)
    assert area == 6 and (mask == masks[0]).all()
    tie = np.zeros((8, 8), bool)
    tie[0, 0:3], tie[5, 0:3] = True, True           # two of 3 cells: the first in label (raster) order
    masks, areas = components(tie, 1)
    assert areas == [3, 3] and masks[0][0, 0:3].all() and masks[1][5, 0:3].all()
    assert largest_component(tie, 1)[0][0, 0:3].all() and not largest_component(tie, 1)[0][5].any()
    assert largest_component(m, 7)[1] == 0 and not largest_component(m, 7)[0].any()


def test_the_goal_choice_is_a_config_key_that_needs_the_evidence_decision():
    from calnav.envs.config import plain_dict
    from calnav.eval.config import ConfigError, load_config

    cfg = load_config(None, ["agent.decision=evidence", "agent.goal_choice=evidence"]).agent
    assert cfg.goal_choice == "evidence" and plain_dict(cfg)["goal_choice"] == "evidence"
    with pytest.raises(ConfigError, match="unknown goal choice 'evidense' for agent.goal_choice; valid choices: "
                                          "largest, evidence"):
        load_config(None, ["agent.decision=evidence", "agent.goal_choice=evidense"])
    with pytest.raises(ConfigError, match="agent.goal_choice=evidence .* needs agent.decision=evidence, got "
                                          "agent.decision=threshold"):
        load_config(None, ["agent.goal_choice=evidence"])
    with pytest.raises(ConfigError, match="agent.goal_choice_margin must be in"):
        load_config(None, ["agent.goal_choice_margin=1.5"])
    saved = plain_dict(AgentConfig())   # at their defaults the keys stay out of saved configs
    assert "goal_choice" not in saved and "goal_choice_margin" not in saved


def dataclasses_replace(cfg, **kw):
    import dataclasses

    return dataclasses.replace(cfg, **kw)
