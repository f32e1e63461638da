"""The agent in a house with storeys (``agent.storeys``, ``agent.storey_policy``): stairs read as
steps and not obstacles, a raised seat is no flight, the floor height follows the stairs from
depth alone, and a single-storey config still builds the single-storey agent."""
from __future__ import annotations

import numpy as np

from calnav.agent.config import AgentConfig
from calnav.agent.semantic_map import MapChannels, MapState
from calnav.agent.storeys import STEP_M, Storey, StoreyMapBuilder
from calnav.mapping.config import MappingConfig

N = 80   # map cells (5 cm): a 4 m square


def _storey() -> Storey:
    cfg = AgentConfig(map_size_m=N * 0.05)
    state = MapState.empty(np.zeros(2), cfg, 3)
    return Storey.new(state, 0.0, 0)


def _staircase(st: Storey) -> None:
    """Floor at 0 everywhere seen; a flight rising 0.17 m every 6 cells along +col from col 40
    in rows 10-30; a 0.45 m seat in rows 50-60, cols 10-20."""
    st.elev[:] = 0.0
    for k in range(6):
        st.elev[10:30, 40 + 6 * k:46 + 6 * k] = 0.17 * (k + 1)
    st.elev[50:60, 10:20] = 0.45
    st.top[:] = st.elev
    st.state.bbox = [0, N - 1, 0, N - 1]


def test_steps_are_not_obstacles_but_a_seat_edge_and_a_wall_are():
    cfg = AgentConfig(map_size_m=N * 0.05)
    st = _storey()
    _staircase(st)
    st.top[70, 70] = 1.0   # a wall point a metre above the floor
    builder = StoreyMapBuilder(cfg, MappingConfig(), ("floor", "wall", "chair"))
    builder.storey = st
    builder.recompute_obstacles(st.state)
    obst = st.state.channels[MapChannels.OBSTACLE]
    assert not obst[11:29, 40:70].any()          # every tread: one rise above the last, below STEP_M
    assert obst[10, 50] and obst[20, 75]         # ... but its open sides and its far end are drops
    assert obst[50:60, 10:20].any() and obst[55, 10] and not obst[55, 9]   # the seat's raised edge
    assert obst[70, 70]
    assert 0.17 < STEP_M < 0.45


def test_flights_find_the_stairs_and_not_the_seat():
    st = _storey()
    _staircase(st)
    free = np.ones((N, N), bool)
    win = (slice(0, N), slice(0, N))
    first = st.flights(free, win, +1, 0.05)
    rows, cols = np.nonzero(first)
    assert first.any() and set(np.unique(cols)) <= set(range(40, 46)) and rows.min() >= 10 and rows.max() < 30
    assert not st.flights(free, win, -1, 0.05).any()   # nothing leads down
    # one step at a time up the flight, and every lower floor when going down
    nxt = st.next_steps(free, win, 0.34, +1)
    assert set(np.unique(np.nonzero(nxt[10:30])[1])) == set(range(52, 58))
    down = st.next_steps(free, win, 0.68, -1, any_lower=True)
    assert down[20, 0] and down[20, 41] and not down[20, 64]


def test_single_storey_config_builds_the_single_storey_agent():
    from calnav.agent.policy import PeanutAgent
    from calnav.agent.storey_policy import StoreyPeanutAgent
    from calnav.eval.config import agent_setup, load_config

    one = PeanutAgent.from_setup(agent_setup(load_config("configs/objectnav.yaml", ["agent.segmenter=gt"])))
    two = PeanutAgent.from_setup(agent_setup(load_config("configs/objectnav.yaml",
                                                         ["agent.segmenter=gt", "env.dataset.storeys=2"])))
    assert type(one) is PeanutAgent and type(two) is StoreyPeanutAgent


def test_the_agent_climbs_and_knows_its_height():
    """A crossing episode (start downstairs, goal upstairs): the agent's floor height, found
    from depth alone, follows the true floor up the stairs within a rise or two, and it ends on
    the goal's storey."""
    from calnav.agent.navigator import EpisodeAgent, Navigator
    from calnav.envs.episodes import load_split
    from calnav.envs.objectnav_env import ObjectNavEnv
    from calnav.eval.config import agent_setup, load_config

    cfg = load_config("configs/objectnav.yaml", ["env.dataset.storeys=2", "env.resolution=160x120",
                                                  "agent.segmenter=gt", "env.dataset.val_scenes=1"])
    eps = [e for e in load_split("val", cfg.env, progress=False) if e.start_storey == 0 and e.goal_storey == 1]
    env = ObjectNavEnv(config=cfg.env, episodes=eps[:1])
    agent = EpisodeAgent(Navigator(agent_setup(cfg)))
    obs, _ = env.reset(options={"episode_index": 0})
    agent.reset(obs)
    a, errors, storeys, done = agent.navigator.agent, [], [], False
    start_floor = env.navgrid.floor_height(env.position, env.layer)
    while not done:
        obs, _, terminated, truncated, info = env.step(agent.act(obs).action)
        done = terminated or truncated
        errors.append(a.floor_z - (env.navgrid.floor_height(env.position, env.layer) - start_floor))
        storeys.append(info["storey"])
    assert 1 in storeys, "the agent never went up the stairs"
    assert np.percentile(np.abs(errors), 90) < 0.4


def test_stairs_are_kept_out_of_a_storeys_exploration():
    """Frontiers on the stairs (and near them) walk the agent off the storey it explores: the
    selector keeps them out while the storey's own floor has frontiers."""
    from calnav.agent.goal_selection import FrontierSelector
    from calnav.agent.storeys import OFF_FLOOR_MARGIN_M

    st = _storey()
    _staircase(st)
    win = (slice(0, N), slice(0, N))
    off = st.off_floor(win, 0.05)
    margin = int(OFF_FLOOR_MARGIN_M / 0.05)
    assert off[10:30, 40:76].all() and off[20, 40 - margin + 1] and not off[20, 40 - margin - 2]
    assert off[50:60, 10:20].all()     # a seat top is another level too
    assert not off[40, 30] and not off[75, 30]   # the storey's own floor
    sel = FrontierSelector(AgentConfig(map_size_m=N * 0.05), ("floor",), ("chair",))
    sel.reset(N, "chair")
    sel.elsewhere = off
    assert (sel._excluded(win) == off).all()
    sel.elsewhere = None
    assert not sel._excluded(win).any()


def test_a_storey_met_on_the_stairs_starts_with_the_flight():
    """The storey the agent reaches part-way up a flight starts with what the storey below knows
    of the flight (its next frames register at once), not with the floor far below it."""
    below = _storey()
    _staircase(below)
    below.reg[:] = below.elev
    z = 0.17 * 6 + 0.3    # part-way up: the top tread lies within the switch distance, the floor not
    above = Storey.new(_storey().state, z, +1).inherit(below, z)
    assert np.array_equal(above.reg, below.reg)
    assert np.isclose(above.elev[20, 72], 0.17 * 6) and np.isnan(above.elev[75, 5])
    assert above.z_ref == z and above.direction == 1
