"""One YAML loader rule shared by every reader of user YAML: a mapping key written twice is an
error. ``yaml.safe_load`` keeps the last silently -- a config section dropped, a label map's
``wall`` turned into ``ceiling`` -- so calnav's readers build their loaders from this one."""
from __future__ import annotations

from typing import Any, Callable

import yaml


def unique_key_loader(duplicate: Callable[[Any, int, int], Exception]) -> type:
    """A ``yaml.SafeLoader`` subclass that raises ``duplicate(key, first_line, line)`` (1-based
    lines of the YAML text) for a mapping key written twice; subclass it for more rules."""

    class UniqueKeyLoader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            seen: dict = {}
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=deep)
                line = key_node.start_mark.line + 1
                try:
                    repeated = key in seen
                except TypeError:   # an unhashable key: SafeLoader's own error names it
                    continue
                if repeated:
                    raise duplicate(key, seen[key], line)
                seen[key] = line
            return super().construct_mapping(node, deep=deep)

    return UniqueKeyLoader
