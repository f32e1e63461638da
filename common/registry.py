"""Named parts chosen by a config key: one ``Registry`` per kind (agents, fusion strategies,
map builders, goal selectors, backends, ...).

A registry maps a name to its part, given either as the object itself or as a lazy
``"package.module:attribute"`` reference, imported on first ``get``. Lazy references keep
config validation cheap: ``names()`` answers without importing torch or a simulator, so a
config can refuse an unknown name (``check``) before anything heavy loads or any worker starts.

    FUSIONS = Registry("fusion strategy", key="mapping.fusion")
    FUSIONS.add("rbu", "calnav.mapping.fusion:rbu_update", "recursive Bayesian update")
    FUSIONS.check(cfg.mapping.fusion)          # ValueError naming the valid choices
    update = FUSIONS.get(cfg.mapping.fusion)   # the function itself
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any, Callable, Generic, Iterator, TypeVar

T = TypeVar("T")


@dataclass(frozen=True)
class Entry:
    """One registered part: its name, a one-line description, and the part or a lazy
    ``"module:attribute"`` reference to it."""

    name: str
    target: Any
    doc: str = ""


class Registry(Generic[T]):
    """Parts of one ``kind`` by name, in registration order (the order ``names()`` lists)."""

    def __init__(self, kind: str, key: str = "") -> None:
        """kind: what the parts are, for messages ("agent"); key: the config key that chooses
        one ("run.agent"), named in the error for an unknown name ("" = none)."""
        self.kind, self.key = kind, key
        self._entries: dict[str, Entry] = {}

    def add(self, name: str, target: T | str, doc: str = "") -> None:
        """Register ``target`` (the part, or ``"module:attribute"``) as ``name``; a name is
        registered once (a second part under one name would silently shadow the first)."""
        if not name or not isinstance(name, str):
            raise ValueError(f"a {self.kind} name must be a non-empty string, got {name!r}")
        if name in self._entries:
            raise ValueError(f"{self.kind} {name!r} is registered twice")
        if isinstance(target, str) and target.count(":") != 1:
            raise ValueError(f"lazy {self.kind} reference {target!r} must look like 'package.module:attribute'")
        self._entries[name] = Entry(name, target, doc)

    def register(self, name: str, doc: str = "") -> Callable[[T], T]:
        """Decorator form of ``add``: ``@REGISTRY.register("name")`` above a class or function."""
        def decorate(obj: T) -> T:
            self.add(name, obj, doc)
            return obj
        return decorate

    def names(self) -> tuple[str, ...]:
        """The registered names, in registration order (for config validation and messages)."""
        return tuple(self._entries)

    def describe(self) -> dict[str, str]:
        """name -> one-line description (for ``--help`` texts and docs)."""
        return {e.name: e.doc for e in self._entries.values()}

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def unknown(self, name: object) -> ValueError:
        """The error for an unknown name: one line naming the key (if any) and the valid choices."""
        where = f" for {self.key}" if self.key else ""
        return ValueError(f"unknown {self.kind} {name!r}{where}; valid choices: {', '.join(self._entries)}")

    def check(self, name: object) -> str:
        """``name`` if registered; else ValueError naming the valid choices."""
        if not isinstance(name, str) or name not in self._entries:
            raise self.unknown(name)
        return name

    def get(self, name: str) -> T:
        """The part registered as ``name``, importing a lazy reference on first use."""
        entry = self._entries.get(self.check(name))
        if isinstance(entry.target, str):
            module, _, attr = entry.target.partition(":")
            try:
                obj = getattr(importlib.import_module(module), attr)
            except (ImportError, AttributeError) as exc:
                raise ImportError(f"{self.kind} {name!r}: cannot load {entry.target} ({exc})") from exc
            self._entries[name] = entry = Entry(name, obj, entry.doc)
        return entry.target
