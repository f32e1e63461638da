"""The PEANUT-like agent end to end: config wiring, registry, and an episode in a small
generated house with ground-truth segmentation."""
import numpy as np
import pytest

from calnav.eval.config import ConfigError, agent_setup, load_config

MAX_STEPS = 200          # the test episode is short: a few metres
NDF_STEPS = 40           # steps of the NDF / uncertainty-aware observation check


def test_agent_config_keys_and_validation():
    cfg = load_config(None, ["agent.map_type=ndf", "agent.goal_threshold=0.9", "segmenter.gt_confidence=0.95"])
    assert cfg.agent.map_type == "ndf" and cfg.agent.goal_threshold == 0.9
    assert cfg.segmenter.gt_confidence == 0.95
    with pytest.raises(ConfigError, match="map_type"):
        load_config(None, ["agent.map_type=voxels"])
    with pytest.raises(ConfigError, match="goal_threshold"):
        load_config(None, ["agent.goal_threshold=1.5"])
    # the uncertainty-aware band [uncertain_low, goal_threshold) must hold something
    with pytest.raises(ConfigError, match=r"uncertain_low \(0.3\) must be below agent.goal_threshold \(0.3\)"):
        load_config(None, ["agent.uncertainty_aware=true", "agent.goal_threshold=0.3"])
    assert load_config(None, ["agent.goal_threshold=0.3"]).agent.goal_threshold == 0.3   # no band needed
    assert load_config(None, ["agent.uncertainty_aware=true", "agent.goal_threshold=0.3",
                              "agent.uncertain_low=0.2"]).agent.uncertain_low == 0.2


def test_the_config_names_parts_of_the_registries():
    """run.agent, agent.map_type and agent.exploration are checked against the agent package's
    registries when the config loads (one line naming the valid choices), importing no part."""
    from calnav.agent.registry import AGENTS, GOAL_SELECTORS, MAP_BUILDERS
    from calnav.eval.config import RunConfig

    assert AGENTS.names() == ("peanut", "oracle") and RunConfig().agent == "peanut"
    assert MAP_BUILDERS.names() == ("fused", "ndf") and GOAL_SELECTORS.names() == ("frontier", "prediction")
    with pytest.raises(ConfigError, match=r"^run: unknown agent 'orcale' for run.agent; valid choices: peanut, oracle$"):
        load_config(None, ["run.agent=orcale"])
    with pytest.raises(ConfigError, match=r"unknown map type 'voxels' for agent.map_type; valid choices: fused, ndf$"):
        load_config(None, ["agent.map_type=voxels"])
    with pytest.raises(ConfigError, match=r"unknown exploration 'random' .*valid choices: frontier, prediction$"):
        load_config(None, ["agent.exploration=random"])


def test_the_agent_is_composed_of_the_registered_parts(small_setup):
    """agent.map_type and agent.exploration choose the map builder and the goal selector the
    policy composes."""
    import dataclasses

    from calnav.agent.goal_selection import FrontierSelector, PredictionSelector
    from calnav.agent.policy import PeanutAgent
    from calnav.agent.semantic_map import FusedMapBuilder, NdfMapBuilder

    cfg, _ = small_setup
    agent = PeanutAgent(agent_setup(cfg))
    assert type(agent.mapper) is FusedMapBuilder and type(agent.selector) is FrontierSelector
    assert agent.predictor is None
    other = PeanutAgent(agent_setup(dataclasses.replace(cfg, agent=dataclasses.replace(
        cfg.agent, map_type="ndf", exploration="prediction"))))
    assert type(other.mapper) is NdfMapBuilder and type(other.selector) is PredictionSelector
    assert other.predictor is other.selector.predictor


@pytest.fixture(scope="module")
def small_setup():
    import gymnasium as gym

    from calnav import envs

    cfg = load_config(None, ["env.resolution=160x120", "env.dataset.val_scenes=1", "env.dataset.episodes_per_scene=6",
                             f"env.max_episode_steps={MAX_STEPS}", "agent.map_size_m=24",
                             "mapping.initial_alloc_mb=32", "agent.map_resolution=80x60"])
    env = gym.make(envs.ENV_ID, split="val", config=cfg.env)
    return cfg, env


def test_agent_finds_goal_in_small_house(small_setup):
    from calnav.agent.policy import PeanutAgent

    cfg, env = small_setup
    episodes = env.unwrapped.episodes
    index = int(np.argmin([ep.geodesic_distance for ep in episodes]))   # the shortest episode
    agent = PeanutAgent(agent_setup(cfg))
    obs, info = env.reset(options={"episode_index": index})
    agent.reset(obs)
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(agent.act(obs).action)
        done = terminated or truncated
    assert info["success"], f"episode {index}: distance to goal {info['distance_to_goal']:.2f} m after {info['steps']} steps"
    assert info["steps"] < MAX_STEPS, info["steps"]


def test_the_goal_channel_is_found_by_name(small_setup):
    """objectgoal ids index calnav's goal categories; the goal's map channel is where its name
    sits in the segmenter's classes (here a plugin of every calnav class but bed: plant, id 2,
    is channel 1; indexing the segmenter's list by the id would give toilet)."""
    import dataclasses

    from calnav.agent.policy import PeanutAgent

    cfg, env = small_setup
    cfg = dataclasses.replace(cfg, agent=dataclasses.replace(cfg.agent, segmenter="tests.agent.segmenter_plugins:no_bed"))
    agent = PeanutAgent(agent_setup(cfg))
    obs, _ = env.reset(options={"episode_index": 0})
    agent.reset({**obs, "objectgoal": np.array([2])})
    assert (agent.goal_name, agent.goal_channel, agent.class_names[agent.goal_channel]) == ("plant", 1, "plant")
    with pytest.raises(ValueError, match="the goal 'bed' is not among the segmenter's classes"):
        agent.reset({**obs, "objectgoal": np.array([1])})


def test_agent_reads_only_habitat_observations(small_setup):
    """The same actions from Habitat's keys alone (+ semantic for gt) as from the full
    observation: no decision depends on the privileged camera_pose / camera_intrinsics."""
    from calnav.agent.policy import PeanutAgent
    from calnav.envs.task import HABITAT_KEYS, SEMANTIC

    cfg, env = small_setup
    episodes = env.unwrapped.episodes
    index = int(np.argmin([ep.geodesic_distance for ep in episodes]))
    full, reduced = PeanutAgent(agent_setup(cfg)), PeanutAgent(agent_setup(cfg))
    keep = (*HABITAT_KEYS, SEMANTIC)
    obs, _ = env.reset(options={"episode_index": index})
    full.reset(obs)
    reduced.reset({k: obs[k] for k in keep})
    done, steps = False, 0
    while not done:
        action = full.act(obs).action
        assert reduced.act({k: obs[k] for k in keep}).action == action, f"step {steps}"
        obs, _, terminated, truncated, _ = env.step(action)
        done, steps = terminated or truncated, steps + 1
    assert steps > cfg.env.turn_angle_deg and full.info.mode == "stop"


def test_ndf_uncertainty_aware_agent_and_video_panel_on_habitat_observations(small_setup):
    """The NDF baseline with the uncertainty-aware variant also reads only Habitat's keys, and
    the video panel draws from such an agent (first NDF_STEPS steps)."""
    import dataclasses

    from calnav.agent.policy import PeanutAgent
    from calnav.agent.visualize import render_panel
    from calnav.envs.task import HABITAT_KEYS, SEMANTIC

    cfg, env = small_setup
    cfg = dataclasses.replace(cfg, agent=dataclasses.replace(cfg.agent, map_type="ndf", uncertainty_aware=True))
    full, reduced = PeanutAgent(agent_setup(cfg)), PeanutAgent(agent_setup(cfg))
    keep = (*HABITAT_KEYS, SEMANTIC)
    obs, _ = env.reset(options={"episode_index": 0})
    full.reset(obs)
    reduced.reset({k: obs[k] for k in keep})
    for step in range(NDF_STEPS):
        action = full.act(obs).action
        last = reduced.act({k: obs[k] for k in keep})
        assert last.action == action, f"step {step}"
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            break
    panel = render_panel(last)
    assert panel.ndim == 3 and panel.shape[2] == 3 and panel.std() > 0


class TrapWorld:
    """A world the agent cannot see (every depth pixel invalid, as when facing holes in a scan)
    whose forward moves are blocked in every heading but one, like a start in a one-cell neck of
    a scanned house's navigable floor. Observations are Habitat's keys (gt semantics: void)."""

    def __init__(self, cfg, open_heading_deg: float):
        w, h = cfg.env.resolution
        self.shape, self.xy, self.yaw = (h, w), np.zeros(2), 0.0
        self.open = np.deg2rad(open_heading_deg)
        self.turn, self.step_m = np.deg2rad(cfg.env.turn_angle_deg), cfg.env.forward_step_m
        self.moves = []   # step indices of forward moves that moved

    def obs(self) -> dict:
        h, w = self.shape
        return {"rgb": np.zeros((h, w, 3), np.uint8), "depth": np.zeros((h, w, 1), np.float32),
                "gps": np.array([self.xy[0], -self.xy[1]], np.float32),
                "compass": np.array([self.yaw], np.float32), "objectgoal": np.array([0]),
                "semantic": np.full((h, w), -1, np.int16)}

    def step(self, action: int, index: int) -> None:
        from calnav.envs.task import Action, wrap_angle

        if action == Action.TURN_LEFT:
            self.yaw = wrap_angle(self.yaw + self.turn)
        elif action == Action.TURN_RIGHT:
            self.yaw = wrap_angle(self.yaw - self.turn)
        elif action == Action.MOVE_FORWARD and (abs(wrap_angle(self.yaw - self.open)) < 1e-3 or self.moves):
            self.xy = self.xy + self.step_m * np.array([np.cos(self.yaw), np.sin(self.yaw)])
            self.moves.append(index)


@pytest.mark.parametrize("open_heading_deg", [150.0, -90.0])
def test_agent_escapes_a_trap_it_cannot_see(open_heading_deg):
    """Blind and blocked in all headings but one, the agent still leaves within a bounded number
    of steps (opening spin + the no-progress watchdog + one full escape), and keeps moving."""
    from calnav.agent.policy import PeanutAgent
    from calnav.envs.task import Action

    cfg = load_config(None, ["env.resolution=64x48", "agent.map_resolution=64x48", "agent.map_size_m=16",
                             "mapping.initial_alloc_mb=16"])
    world, agent = TrapWorld(cfg, open_heading_deg), PeanutAgent(agent_setup(cfg))
    agent.reset(world.obs())
    for i in range(200):
        action = agent.act(world.obs()).action
        assert action != Action.STOP, f"stopped at step {i}"
        world.step(action, i)
    a = cfg.agent
    bound = round(360 / cfg.env.turn_angle_deg) + a.stuck_steps + a.untrap_steps + 2
    assert world.moves and world.moves[0] <= bound, world.moves[:3]
    assert len(world.moves) >= 10    # then it keeps moving (no loop in place)


def _prediction_selector(**overrides):
    """A PredictionSelector (the shipped predictor) on an empty 16 m map around the origin: the
    selector, the map state, the whole map as the window, its centre and an all-free map."""
    import dataclasses

    from calnav.agent.config import AgentConfig
    from calnav.agent.goal_selection import PredictionSelector
    from calnav.agent.segmenters.base import default_class_names, goal_categories
    from calnav.agent.semantic_map import MapState

    cfg = dataclasses.replace(AgentConfig(map_size_m=16, exploration="prediction"), **overrides)
    classes = default_class_names()
    selector = PredictionSelector(cfg, classes, tuple(g for g in goal_categories() if g in classes))
    state = MapState.empty(np.zeros(2), cfg, len(classes))
    n = state.size
    selector.reset(n, "chair")
    return selector, state, (slice(0, n), slice(0, n)), (n // 2, n // 2), np.ones((n, n), bool)


@pytest.mark.parametrize("replan_seen", [False, True])
def test_a_predicted_goal_is_rechosen_once_its_cell_is_seen(replan_seen, monkeypatch):
    """agent.prediction_replan_seen: a long-term goal from the prediction (an unexplored cell)
    is re-chosen as soon as its cell is explored; an unseen one, or a frontier goal (explored by
    definition), is kept until replan_steps."""
    from calnav.agent.semantic_map import MapChannels

    selector, state, win, here, free = _prediction_selector(prediction_replan_seen=replan_seen)
    calls = []
    monkeypatch.setattr(selector, "_choose", lambda st, w, rc, free_, current=None: calls.append(rc))   # None: nothing chosen
    explored = state.channels[MapChannels.EXPLORED]
    for predicted, seen, rechosen in [(True, False, False), (True, True, replan_seen), (False, True, False)]:
        calls.clear()
        selector.goal, selector.age, selector.predicted = (here[0] + 20, here[1]), 0, predicted
        explored[selector.goal] = seen
        selector.select(state, win, here, free)
        assert bool(calls) == rechosen, (predicted, seen)


def test_a_periodic_rechoice_never_returns_to_the_predicted_goal_just_left(monkeypatch):
    """PEANUT's rule: predicted goals A -> B, then A again at a periodic re-choice keeps B (no
    walking back and forth between two goals of near-equal value); once B is seen or reached
    (no current goal), A may be chosen; a goal within goal_dilation_m of A counts as A; with
    agent.prediction_no_switch_back=false the agent flips back."""
    import dataclasses

    selector, state, win, here, free = _prediction_selector()
    a, b, a_moved = (here[0] + 30, here[1]), (here[0] - 30, here[1]), (here[0] + 33, here[1] + 2)
    offers = iter([a, b, a_moved, a])
    monkeypatch.setattr(selector, "_predicted", lambda st, w, rc, free_: next(offers))
    choose = selector._choose
    assert choose(state, win, here, free) == a and choose(state, win, here, free, current=a) == b
    assert choose(state, win, here, free, current=b) == b and selector.goal == b    # A (moved) again: keep B
    assert choose(state, win, here, free, current=None) == a and selector.goal == a  # B seen: A is fine
    selector.cfg = dataclasses.replace(selector.cfg, prediction_no_switch_back=False)
    offers = iter([b, a])
    assert choose(state, win, here, free, current=a) == b and choose(state, win, here, free, current=b) == a   # off: flips


@pytest.mark.parametrize("goal_choice", ["largest", "evidence"])
def test_the_evidence_decision_tests_the_goal_before_it_stops(small_setup, goal_choice):
    """agent.decision=evidence in the whole agent: the STOP at the goal came after the
    uncertainty test read the goal's views (gt: per-view probability 0.9), and the episode
    succeeds as with the threshold decision; with the goal chosen by its evidence too."""
    import dataclasses

    from calnav.agent.policy import PeanutAgent

    cfg, env = small_setup
    cfg = dataclasses.replace(cfg, agent=dataclasses.replace(cfg.agent, decision="evidence", goal_choice=goal_choice))
    episodes = env.unwrapped.episodes
    index = int(np.argmin([ep.geodesic_distance for ep in episodes]))
    agent = PeanutAgent(agent_setup(cfg))
    obs, info = env.reset(options={"episode_index": index})
    agent.reset(obs)
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(agent.act(obs).action)
        done = terminated or truncated
    ev = agent.decision.last
    assert info["success"] and agent.info.mode == "stop"
    if goal_choice == "evidence":   # the goal was chosen by the evidence choice, which held it to the end
        from calnav.agent.evidence import EvidenceChoice

        assert isinstance(agent.detector.choice, EvidenceChoice) and agent.detector.choice.pursued.any()
    assert ev is not None and ev.n >= cfg.agent.evidence_min_views and ev.mean > 0.8, ev
    assert ev.lower_bound(cfg.agent.evidence_z) >= cfg.agent.evidence_confidence
