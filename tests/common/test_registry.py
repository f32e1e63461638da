"""common.registry: names, lazy loading, one-line errors for unknown and twice-registered names."""
from __future__ import annotations

import pytest

from calnav.common.registry import Registry


def test_names_in_registration_order_and_lazy_get() -> None:
    reg: Registry = Registry("thing", key="a.b")
    reg.add("join", "os.path:join", "joins paths")
    reg.add("direct", len)
    assert reg.names() == ("join", "direct")
    assert reg.describe() == {"join": "joins paths", "direct": ""}
    import os.path
    assert reg.get("join") is os.path.join
    assert reg.get("direct") is len
    assert "join" in reg and "nope" not in reg and len(reg) == 2


def test_unknown_name_names_key_and_choices() -> None:
    reg: Registry = Registry("agent", key="run.agent")
    reg.add("peanut", "os:getcwd")
    reg.add("oracle", "os:getpid")
    with pytest.raises(ValueError, match=r"^unknown agent 'x' for run.agent; valid choices: peanut, oracle$"):
        reg.check("x")
    with pytest.raises(ValueError, match="unknown agent"):
        reg.get("x")


def test_refuses_twice_registered_and_malformed_reference() -> None:
    reg: Registry = Registry("part")

    @reg.register("a")
    def a() -> None:
        pass

    with pytest.raises(ValueError, match="registered twice"):
        reg.add("a", "os:getcwd")
    with pytest.raises(ValueError, match="module:attribute"):
        reg.add("b", "os.getcwd")
    reg.add("missing", "os:no_such_attribute")
    with pytest.raises(ImportError, match="cannot load os:no_such_attribute"):
        reg.get("missing")
