"""Command-line arguments that set config keys (``--agent NAME`` is ``run.agent=NAME``), declared
once per command on its flag (``eval.arguments.arg(..., sets=KEY)``; ``Command.shorthands()``) and
set by one function, ``apply_shorthands``.

A shorthand given next to an override of a key it sets is refused, one line naming both (the
shorthand never silently replaces the override, nor the override the shorthand). A shorthand's
``default`` (the command's own value of the key, e.g. ``collect-maps`` explores the train
split) is set when the argument is not given, under the overrides, which may change it. A
shorthand without an option is a value the command itself always sets (``scan-houses`` scans:
``env.dataset.style=scanned``); an override of its key is refused too.

``load_command_config(args)`` is what a command's config loader calls: the command's YAML file
(``args.config``) and overrides with its shorthands applied, validated against its sections.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from calnav.eval.config import EPISODE_SECTIONS, Config, ConfigError, load_config, migrate_key


@dataclass(frozen=True)
class Shorthand:
    """One argument that sets config keys. ``option``: as typed ("--agent", "--quick"; a
    positional's name, "target"; "" for a value the command always sets). ``key``: the config
    key it sets; ``convert``: the argument's value -> the key's value (default: as given; a
    result of None sets nothing); ``preset``: for a flag (``--quick``) or an option-less
    shorthand, the (key, value) pairs it sets instead of ``key``; ``default``: the argument's
    value when it is not given (None: then it sets nothing)."""

    option: str
    key: str = ""
    convert: Callable[[Any], Any] | None = None
    default: Any = None
    preset: tuple[tuple[str, Any], ...] = ()

    @property
    def dest(self) -> str:
        """The argparse attribute holding the argument's value."""
        return self.option.lstrip("-").replace("-", "_")

    def keys(self) -> tuple[str, ...]:
        """The config keys it may set."""
        return tuple(k for k, _ in self.preset) or (self.key,)

    def settings(self, value: Any) -> list[tuple[str, Any]]:
        """The (key, value) pairs the argument's ``value`` sets."""
        if self.preset:
            return list(self.preset)
        value = self.convert(value) if self.convert is not None else value
        return [] if value is None else [(self.key, value)]


def fixed(key: str, value: Any) -> Shorthand:
    """A value the command always sets (an override of ``key`` is refused)."""
    return Shorthand("", preset=((key, value),))


@dataclass(frozen=True)
class Schema:
    """What one command reads of the root config: its sections and its shorthands."""

    command: str
    sections: tuple[str, ...] = EPISODE_SECTIONS
    shorthands: tuple[Shorthand, ...] = ()


def _given(value: Any) -> bool:
    return value is not None and value is not False


def apply_shorthands(args: Any, schema: Schema, overrides: list[str]) -> list[str]:
    """``overrides`` with the shorthands of ``schema`` set from ``args`` (argparse's namespace):
    a given argument's keys after the overrides (an override of one of them is a ConfigError
    naming both), a missing argument's ``default`` before them (so an override changes it)."""
    overridden: dict[str, str] = {}   # config key -> the override that sets it
    for text in overrides:
        overridden.setdefault(migrate_key(text.partition("=")[0].strip()), text)
    before, after = [], []
    for sh in schema.shorthands:
        value = getattr(args, sh.dest, None) if sh.option else True
        if not _given(value):
            if sh.default is not None:
                before += [f"{k}={v}" for k, v in sh.settings(sh.default)]
            continue
        for key, v in sh.settings(value):
            if key in overridden:
                raise ConfigError(_conflict(schema.command, sh, value, key, v, overridden[key]))
            after.append(f"{key}={v}")
    return [*before, *overrides, *after]


def _conflict(command: str, sh: Shorthand, value: Any, key: str, setting: Any, override: str) -> str:
    """The one-line refusal of a shorthand and an override that set the same key."""
    if not sh.option:
        return f"calnav {command} sets {key}={setting} itself; remove the override {override}"
    if sh.preset:
        what = f"{sh.option} (which sets {key}={setting})"
    elif sh.option.startswith("-"):
        what = f"{sh.option} {value}"
    else:
        what = f"the {sh.option} {value}"
    return f"{what} and the override {override} both set {key}: give one of them"


def load_command_config(args: Any, overrides: list[str] | None = None, config: str | Path | None = None) -> Config:
    """The config the command of ``args`` runs (``args.schema``, set by ``eval.cli.parse_args``):
    ``config`` (default ``args.config``) and ``overrides`` (default ``args.overrides``) with its
    shorthands applied, validated against its sections."""
    schema: Schema = args.schema
    overrides = list(args.overrides if overrides is None else overrides)
    return load_config(getattr(args, "config", None) if config is None else config,
                       apply_shorthands(args, schema, overrides), sections=schema.sections, command=schema.command)
