"""agent.dijkstra: the compiled geometric Dijkstra gives scikit-image's MCP_Geometric distances
bit for bit (full searches everywhere, early-stopped searches at their targets)."""
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from skimage.graph import MCP_Geometric

from calnav.agent.dijkstra import geodesic


def skimage_distances(costs, sources, targets=None):
    ends = None if targets is None or len(targets) == 0 else [tuple(t) for t in targets]
    dist, _ = MCP_Geometric(costs, fully_connected=True).find_costs([tuple(s) for s in sources], ends=ends)
    return dist


def test_hand_computed_grid():
    # 3 x 3, unit cost except the centre (cost 3); from the top-left corner:
    #  0.5 * (1 + 1) = 1 per straight step; the centre diagonally sqrt(2) / 2 * (1 + 3) (through
    #  a neighbour: 1 + 0.5 * (1 + 3) = 3); the far corner skirts the centre: 1 + sqrt(2) + 1
    costs = np.array([[1, 1, 1], [1, 3, 1], [1, 1, 1]], float)
    d = geodesic(costs, np.array([[0, 0]]))
    assert d[0, 0] == 0.0 and d[0, 1] == 1.0 and d[0, 2] == 2.0
    assert d[1, 1] == math.sqrt(2.0) * 0.5 * 4.0
    assert math.isclose(d[2, 2], 2.0 + math.sqrt(2.0), rel_tol=1e-15)
    walled = costs.copy()
    walled[:, 1] = np.inf                     # a wall cuts the grid in two
    d = geodesic(walled, np.array([[0, 0]]))
    assert np.isinf(d[:, 1:]).all() and d[2, 0] == 2.0


def test_sources_on_walls_are_skipped_and_targets_stop_the_search():
    costs = np.ones((40, 40))
    costs[0, 0] = np.inf
    d = geodesic(costs, np.array([[0, 0], [20, 20]]), targets=np.array([[20, 22]]))
    assert d[20, 22] == 2.0 and np.isinf(d[0, 0])
    assert np.isinf(d).sum() > 1000            # most of the grid never reached the heap


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(2, 40), w=st.integers(2, 40),
       wall=st.floats(0.0, 0.5), n_targets=st.integers(0, 4))
def test_matches_skimage_mcp_geometric(seed, h, w, wall, n_targets):
    rng = np.random.default_rng(seed)
    costs = rng.choice([1.0, 1.5, 5.0], size=(h, w))
    costs[rng.random((h, w)) < wall] = np.inf
    sources = rng.integers(0, (h, w), size=(rng.integers(1, 4), 2))
    costs[sources[:, 0], sources[:, 1]] = 1.0
    full = geodesic(costs, sources)
    np.testing.assert_array_equal(full, skimage_distances(costs, sources))
    if n_targets:
        targets = rng.integers(0, (h, w), size=(n_targets, 2))
        targets = targets[np.isfinite(costs[targets[:, 0], targets[:, 1]])]
        early = geodesic(costs, sources, targets)
        ref = skimage_distances(costs, sources, targets)
        for r, c in targets:
            assert early[r, c] == full[r, c] == ref[r, c] or np.isinf(full[r, c])


def test_compiles_without_a_writable_cache():
    """Where numba finds nowhere to cache (read-only install and home, simulated by allowing
    only its IPython locator, which never applies to a file), the kernel still compiles."""
    import os
    import subprocess
    import sys

    code = ("import numpy as np; from calnav.agent.dijkstra import geodesic, _dijkstra8; "
            "print(geodesic(np.ones((2, 2)), np.array([[0, 0]]))[1, 1], type(_dijkstra8._cache).__name__)")
    env = dict(os.environ, NUMBA_CACHE_LOCATOR_CLASSES="IPythonCacheLocator")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [repr(math.sqrt(2.0)), "NullCache"]
