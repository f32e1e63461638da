"""Validation of a nested config dict against a config dataclass (``build_dataclass``), with
calnav's one-line errors (``ConfigError``): the machinery under ``eval.config``'s loader.

The config sections are plain dataclasses owned by their packages (envs, mapping, agent, ...);
pydantic validates a nested dict against them (types, Literal choices, finite numbers, then each
section's own __post_init__ range checks) and ``_config_error`` turns its first error into
calnav's one line naming the key and the valid keys or choices. The validation settings are
attached here, once per dataclass, so the packages stay free of pydantic.
"""
from __future__ import annotations

import dataclasses
import re
import types
import typing
from typing import Any, Literal

from pydantic import ConfigDict, TypeAdapter, ValidationError


class ConfigError(ValueError):
    """A config key or value is invalid; the message names it and the valid choices."""


# "WxH" sizes (160x120). YAML 1.1 reads "0x0" / "0x10" as hexadecimal integers (0, 16), so the
# loader keeps text of this form a string and ``_prepare`` splits it for a size (tuple) field.
WXH_RE = re.compile(r"^\d+x\d+$")


PYDANTIC_CONFIG = ConfigDict(extra="forbid", allow_inf_nan=False, coerce_numbers_to_str=True)
_ADAPTERS: dict[type, TypeAdapter] = {}

# pydantic error type -> what calnav says was expected
_EXPECTED = {
    "float_parsing": "a number", "float_type": "a number", "finite_number": "a finite number",
    "int_parsing": "an integer", "int_type": "an integer", "int_from_float": "an integer",
    "bool_parsing": "true or false", "bool_type": "true or false",
    "tuple_type": "a list (or 'WxH')", "list_type": "a list", "dict_type": "a mapping",
    "string_type": "a string", "dataclass_type": "a mapping", "dataclass_exact_type": "a mapping",
}


def _with_pydantic_config(cls: type) -> None:
    """Attach PYDANTIC_CONFIG to ``cls`` and every dataclass its fields hold."""
    if "__pydantic_config__" in cls.__dict__:
        return
    cls.__pydantic_config__ = PYDANTIC_CONFIG
    for tp in typing.get_type_hints(cls).values():
        for t in (tp, *typing.get_args(tp)):
            if dataclasses.is_dataclass(t):
                _with_pydantic_config(t)


def _adapter(cls: type) -> TypeAdapter:
    if cls not in _ADAPTERS:
        _with_pydantic_config(cls)
        _ADAPTERS[cls] = TypeAdapter(cls)
    return _ADAPTERS[cls]


def _field_path(cls: type, loc: tuple) -> tuple[list[str], type | None, Any]:
    """Walk ``loc`` (a pydantic error location) through ``cls``'s fields: (the config key's
    parts, the dataclass holding the last one, the last one's type). Union member tags and list
    indices in ``loc`` are not keys."""
    parts, holder, tp = [], cls, cls
    for item in loc:
        if dataclasses.is_dataclass(tp) and isinstance(item, str):
            hints = typing.get_type_hints(tp)
            holder = tp
            parts.append(item)
            tp = section_type(hints.get(item))
            if tp is None:
                break
            continue
        if typing.get_origin(tp) is dict:   # a mapping's key
            parts.append(str(item))
            tp = typing.get_args(tp)[1]
            continue
        if isinstance(item, int):       # a list element
            args = typing.get_args(tp)
            tp = args[0] if args else None
            parts[-1] = f"{parts[-1]}[{item}]" if parts else f"[{item}]"
            continue
        members = [a for a in typing.get_args(tp) if a is not type(None)]   # a union member's tag
        tp = next((a for a in members if getattr(a, "__name__", str(a)) in str(item)), None)
    return parts, holder, tp


def section_type(tp: Any) -> Any:
    """``X`` of ``X | None`` (a root config section), else ``tp``."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        members = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(members) == 1:
            return members[0]
    return tp


def _prepare(cls: type, data: dict, prefix: str) -> dict:
    """What pydantic's lax mode would read differently from calnav's configs: a ``WxH`` string
    for a size (2-tuple) field is split, and true / false for a number is refused (pydantic
    would take it as 1 / 0)."""
    hints, out = typing.get_type_hints(cls), dict(data)
    for name, value in data.items():
        tp, key = section_type(hints.get(name)), f"{prefix}.{name}" if prefix else name
        if typing.get_origin(tp) is tuple and isinstance(value, str) and WXH_RE.match(value):
            out[name] = value.split("x")
        elif tp in (int, float) and isinstance(value, bool):
            raise ConfigError(f"bad value for {key}: {value!r}; expected {_EXPECTED[f'{tp.__name__}_type']}")
        elif typing.get_origin(tp) in (list, tuple) and isinstance(value, (list, tuple)):
            items = typing.get_args(tp)
            for i, v in enumerate(value):   # a number list's items: list[float], tuple[int, int], tuple[float, ...]
                item_tp = items[0] if len(items) == 1 or items[-1] is Ellipsis else items[min(i, len(items) - 1)]
                if item_tp in (int, float) and isinstance(v, bool):
                    raise ConfigError(f"bad value for {key}: {value!r}; expected a list of "
                                      f"{'integers' if item_tp is int else 'numbers'}")
        elif dataclasses.is_dataclass(tp) and isinstance(value, dict):
            out[name] = _prepare(tp, value, key)
    return out


# which of pydantic's errors to report first: an unknown key explains a "missing" one beside it
_ERROR_ORDER = {"unexpected_keyword_argument": 0, "missing": 2}


def _config_error(cls: type, exc: ValidationError, prefix: str) -> ConfigError:
    """calnav's one-line message for pydantic's first error."""
    err = min(exc.errors(include_url=False), key=lambda e: _ERROR_ORDER.get(e["type"], 1))
    cause = err.get("ctx", {}).get("error")
    if isinstance(cause, ConfigError):   # raised by a nested build_dataclass (a section's variants)
        return cause
    parts, holder, tp = _field_path(cls, err["loc"])
    key = ".".join(p for p in [prefix, *parts] if p)
    kind, value = err["type"], err.get("input")
    if kind == "unexpected_keyword_argument":
        section = ".".join(p for p in [prefix, *parts[:-1]] if p)
        where = f"under '{section}'" if section else "at the top level"
        names = ", ".join(f.name for f in dataclasses.fields(holder))
        return ConfigError(f"unknown config key '{key}'; valid keys {where}: {names}")
    if kind == "literal_error":
        choices = ", ".join(map(str, typing.get_args(tp))) if typing.get_origin(tp) is Literal else \
            err["ctx"]["expected"]
        return ConfigError(f"bad value for {key}: {value!r}; valid choices: {choices}")
    if kind == "missing" and isinstance(err["loc"][-1], int):   # a fixed-length tuple given too few items
        parts, _, tp = _field_path(cls, err["loc"][:-1])
        key = ".".join(p for p in [prefix, *parts] if p)
        return ConfigError(f"bad value for {key}: {value!r}; expected {len(typing.get_args(tp))} items")
    if kind == "missing":
        return ConfigError(f"missing config key '{key}'")
    if kind == "value_error":            # a section's own __post_init__ range check
        return ConfigError(f"{key or cls.__name__}: {err['ctx']['error']}")
    if kind in ("too_short", "too_long"):
        return ConfigError(f"bad value for {key}: {value!r}; expected {len(typing.get_args(tp))} items")
    expected = _EXPECTED.get(kind)
    if expected is None:
        return ConfigError(f"bad value for {key}: {value!r}; {err['msg']}")
    if expected == "a mapping" and dataclasses.is_dataclass(tp):
        expected = f"a mapping of {tp.__name__} keys"
    return ConfigError(f"bad value for {key}: {value!r}; expected {expected}")


def build_dataclass(cls: type, data: dict, prefix: str = "") -> Any:
    """Build ``cls`` from a (possibly partial) nested dict, validating every key and value
    (``prefix``: the dotted key ``data`` sits under, for messages)."""
    if not isinstance(data, dict):
        raise ConfigError(f"bad value for {prefix or cls.__name__}: {data!r}; expected a mapping of "
                          f"{cls.__name__} keys")
    try:
        return _adapter(cls).validate_python(_prepare(cls, data, prefix))
    except ValidationError as exc:
        raise _config_error(cls, exc, prefix) from None
