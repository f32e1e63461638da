"""A ``calnav`` command declared once, beside its main: a dataclass of its flags (each field's
type, default, help, valid range and the config key it is a shorthand of) and a ``Command``
naming that dataclass, the main and what of the root config it reads. ``eval.parser`` builds
the command's argparse parser from them, ``eval.cli`` dispatches, ``docs/cli.md``'s flag table is
rendered from them (``flag_rows``).

    @dataclass
    class TuneArgs:
        extend: int = arg(0, "while the best threshold is on the grid's edge, try up to this many more",
                          range=Range(0, 100, "thresholds"))

    COMMAND = Command(TuneArgs, main_tune, tune_configs, config="configs/objectnav.yaml")

A field's annotation gives the argparse type: ``bool`` a flag (``store_true``), ``int`` /
``float`` (optionally ``| None``) a number, ``str`` text, ``list[str]`` several words (``nargs``)
or a repeatable option (``repeat``), ``Literal[...]`` its choices. The options ``--config`` and
the ``KEY=VALUE`` overrides are not fields: ``Command.config`` / ``Command.overrides`` declare them
(``eval.parser.add_config_args``).
"""
from __future__ import annotations

import dataclasses
import sys
import types
import typing
from dataclasses import dataclass, field
from typing import Any, Callable

from calnav.common.ranges import Range
from calnav.eval.config import EPISODE_SECTIONS
from calnav.eval.shorthands import Schema, Shorthand

REQUIRED = object()   # arg(REQUIRED, ...): an option that must be given (its field holds None until parsed)


def arg(default: Any = None, help: str = "", *, metavar: str | None = None, choices: tuple[str, ...] | None = None,
        range: Range | None = None, positional: bool = False, nargs: str | None = None, repeat: bool = False,
        option: str = "", short: str = "", sets: str = "", convert: Callable[[Any], Any] | None = None,
        sets_default: Any = None, preset: tuple[tuple[str, Any], ...] = ()) -> Any:
    """One flag as a dataclass field. default: its value when not given (``REQUIRED``: must be
    given); help: its ``--help`` line; metavar / choices / nargs: argparse's; range: the valid
    interval of a number (``common.ranges``; checked by ``check_args``, None passes); positional:
    an argument without ``--``; repeat: an option given several times (a list); option: its
    spelling when not ``--<field-name>`` (``--from`` of ``source``); short: e.g. ``-m``. sets /
    convert / sets_default / preset: it is the shorthand of config key ``sets``
    (``eval.shorthands.Shorthand``'s key / convert / default / preset)."""
    meta = dict(help=help, metavar=metavar, choices=choices, range=range, positional=positional, nargs=nargs,
                repeat=repeat, option=option, short=short, required=default is REQUIRED,
                sets=sets, convert=convert, sets_default=sets_default, preset=preset)
    value = None if default is REQUIRED else default
    if isinstance(value, list):
        return field(default_factory=lambda: list(value), metadata=meta)
    return field(default=value, metadata=meta)


@dataclass(frozen=True)
class Command:
    """One ``calnav`` command (registered by name and help in ``eval.parser.COMMANDS``). ``main``
    (the CLI) loads the configs once, runs the preflight on them and hands the same objects to the
    command's main, so the preflight checks exactly the configs that run."""

    args: type                  # the dataclass of its flags (fields made with ``arg``)
    main: Callable[..., Any]    # main(args, configs) -> None (or the exit status, with ``status``)
    configs: Callable[[Any], list] | None = None   # configs(args) -> the configs it runs; None: it reads none
    config: str | None = None   # --config's default file; "" = --config without a default file; None: no --config
    config_help: str = ""       # --config's help ("" = "YAML config (default: <config>)")
    overrides: str | None = ""  # help of the KEY=VALUE overrides ("" = the generic one); None: it takes none
    # the preflight's checks (eval.preflight.CHECKS) for what this command uses of its configs
    checks: tuple[str, ...] = ("run", "agent", "study", "mapping")
    sections: tuple[str, ...] = EPISODE_SECTIONS   # the root config's sections it uses (() with no config)
    fixed: tuple[Shorthand, ...] = ()   # values it always sets (eval.shorthands.fixed)
    status: bool = False        # main returns the exit status (0 / 1: a check that found a difference)

    # The loader and the main are looked up in their module when called (a module attribute
    # patched after the registry loaded this Command, as a test does, is the one that runs).
    def load_configs(self, args: Any) -> list:
        """Every config the command runs (all multirun combinations); [] when it reads none."""
        return _current(self.configs)(args) if self.configs is not None else []

    def run_main(self, args: Any, configs: list) -> Any:
        return _current(self.main)(args, configs)

    def fields(self) -> tuple[dataclasses.Field, ...]:
        return dataclasses.fields(self.args)

    def schema(self, name: str) -> Schema:
        """What command ``name`` reads of the root config: its sections and shorthands."""
        return Schema(name, self.sections, self.shorthands())

    def shorthands(self) -> tuple[Shorthand, ...]:
        """Its flags that set config keys (fields with ``sets`` / ``preset``), then ``fixed``."""
        return (*(Shorthand(spelling(f), f.metadata["sets"], f.metadata["convert"], f.metadata["sets_default"],
                            f.metadata["preset"])
                  for f in self.fields() if f.metadata["sets"] or f.metadata["preset"]), *self.fixed)


def _current(function: Callable[..., Any]) -> Callable[..., Any]:
    """``function`` as its module holds it now."""
    return getattr(sys.modules[function.__module__], function.__name__, function)


def spelling(f: dataclasses.Field) -> str:
    """The flag as typed: ``--episodes``, ``--from``; a positional's name."""
    if f.metadata["positional"]:
        return f.name
    return f.metadata["option"] or "--" + f.name.replace("_", "-")


def _base_type(annotation: Any) -> Any:
    """``int | None`` -> int; other annotations unchanged."""
    if isinstance(annotation, types.UnionType) or typing.get_origin(annotation) is typing.Union:
        rest = [a for a in typing.get_args(annotation) if a is not type(None)]
        return rest[0] if len(rest) == 1 else annotation
    return annotation


def argparse_spec(f: dataclasses.Field, annotation: Any) -> tuple[tuple[str, ...], dict[str, Any]]:
    """(names, keyword arguments) of ``parser.add_argument`` for field ``f``."""
    m, tp = f.metadata, _base_type(annotation)
    kw: dict[str, Any] = {"help": m["help"]}
    if m["positional"]:
        names: tuple[str, ...] = (f.name,)
    else:
        names = (*((m["short"],) if m["short"] else ()), spelling(f))
        kw["dest"] = f.name
        kw["default"] = [] if f.default_factory is not dataclasses.MISSING else f.default
        if m["required"]:
            kw["required"] = True
    if tp is bool:
        kw["action"] = "store_true"
        return names, kw
    if typing.get_origin(tp) is typing.Literal:
        kw["choices"] = typing.get_args(tp)
    elif typing.get_origin(tp) is list:
        kw["action" if m["repeat"] else "nargs"] = "append" if m["repeat"] else (m["nargs"] or "+")
    elif tp in (int, float):
        kw["type"] = tp
    for key in ("metavar", "choices", "nargs"):
        if m[key] is not None:
            kw[key] = m[key]
    return names, kw


def add_arguments(parser: Any, command: Command, after_positionals: Callable[[], None] = lambda: None) -> None:
    """Every field of ``command.args`` as an argument of ``parser``: the positionals first (in
    field order), then ``after_positionals()`` (the ``--config`` / overrides arguments: overrides
    take the words after the positionals), then the options."""
    hints = typing.get_type_hints(command.args)
    fields = command.fields()
    for positional in (True, False):
        for f in fields:
            if f.metadata["positional"] is positional:
                names, kw = argparse_spec(f, hints[f.name])
                parser.add_argument(*names, **kw)
        if positional:
            after_positionals()


def check_args(command: Command, args: Any) -> None:
    """ValueError naming the flag (``common.ranges``' message) when a given number is outside its
    field's range."""
    for f in command.fields():
        value = getattr(args, f.name)
        if f.metadata["range"] is not None and value is not None:
            f.metadata["range"].check(spelling(f), value)
