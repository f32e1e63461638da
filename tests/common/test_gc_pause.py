import gc

import pytest

from calnav.common.gc_pause import gc_paused


def test_gc_paused_disables_inside_and_restores_the_previous_state():
    """Enabled before: disabled inside, enabled after (also when the block raises); disabled
    before (a caller's choice): still disabled after."""
    assert gc.isenabled()
    with gc_paused():
        assert not gc.isenabled()
    assert gc.isenabled()
    with pytest.raises(RuntimeError):
        with gc_paused():
            raise RuntimeError("boom")
    assert gc.isenabled()
    gc.disable()
    try:
        with gc_paused():
            with gc_paused():
                assert not gc.isenabled()
            assert not gc.isenabled()
        assert not gc.isenabled()
    finally:
        gc.enable()

