"""Typed configuration: dataclasses loaded from YAML, with dotted CLI overrides.

``load_config("configs/objectnav.yaml", ["env.resolution=160x120", "mapping.fusion=glfs"])``
returns a ``Config``; an unknown key or a bad value raises ``ConfigError`` naming the key and
the valid keys / choices. Every section's defaults live in its package's dataclass, so a YAML
file only states what it changes.
"""
from __future__ import annotations

import dataclasses
import itertools
import re
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import ConfigDict, TypeAdapter, ValidationError

from calnav.common.yaml_keys import unique_key_loader
from calnav.agent.config import AgentConfig
from calnav.envs.config import EnvConfig
from calnav.mapping.config import MappingConfig

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"


class ConfigError(ValueError):
    """A config key or value is invalid; the message names it and the valid choices."""


# "WxH" sizes (160x120). YAML 1.1 reads "0x0" / "0x10" as hexadecimal integers (0, 16), so the
# loader keeps text of this form a string and ``_prepare`` splits it for a size (tuple) field.
WXH_RE = re.compile(r"^\d+x\d+$")


class StrictLoader(unique_key_loader(lambda key, first, line: ConfigError(
        f"duplicate key {key!r} at line {line} (first at line {first}); write each key once"))):
    """SafeLoader that refuses a mapping key written twice (plain YAML keeps the last, silently
    dropping e.g. a whole section) and reads ``WxH`` as text, never as a hex integer."""


StrictLoader.yaml_implicit_resolvers = {k: list(v) for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()}
for _digit in "0123456789":  # checked before YAML's int resolver, which would take 0x0 as hex
    StrictLoader.yaml_implicit_resolvers.setdefault(_digit, []).insert(0, ("tag:yaml.org,2002:str", WXH_RE))


def _yaml_error_text(exc: yaml.YAMLError) -> str:
    """One line: the problem and where (line/column of the YAML text, 1-based)."""
    mark = getattr(exc, "problem_mark", None)
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    return f"{where}{problem}"


def load_yaml_text(text: str, source: str) -> Any:
    """Parse YAML ``text`` with ``StrictLoader``; a syntax error becomes a one-line ConfigError
    naming ``source`` (a file path or an override)."""
    try:
        return yaml.load(text, Loader=StrictLoader)  # noqa: S506 (StrictLoader is a SafeLoader)
    except yaml.YAMLError as exc:
        raise ConfigError(f"YAML syntax error in {source}: {_yaml_error_text(exc)}") from None
    except ConfigError as exc:  # a duplicate key
        raise ConfigError(f"{source}: {exc}") from None


# Names of ``eval.objectnav.agents.AGENTS`` (a test keeps the two in step): the config validates the
# choice without importing any agent.
AgentName = Literal["peanut", "oracle"]
AGENT_NAMES: tuple[str, ...] = AgentName.__args__  # type: ignore[attr-defined]
# Names of ``eval.backends.BACKENDS`` (a test keeps the two in step).
BackendName = Literal["local", "ray"]


@dataclass
class RunConfig:
    """How an experiment runs, and which agent runs it (``eval.objectnav.agents.AGENTS``)."""

    agent: AgentName = "peanut"   # agent that runs the episodes: peanut (semantic map, agent.*) | oracle (shortest path)
    seed: int = 0                 # master random seed
    workers: int = 0              # parallel worker processes; 0 = all cores (backend ray: 0 = no cap on tasks in flight)
    backend: BackendName = "local"  # where work items run (eval.backends): local (this machine's cores) | ray
    ray_address: str = ""         # backend ray: "" = start a local Ray instance; "auto" or "ray://host:port" = join a cluster
    output_dir: str = "runs/latest"  # where results, plots and videos go
    device: str = "cpu"           # torch device for learned models ("cpu", "cuda", "cuda:1")

    def __post_init__(self) -> None:
        if self.workers < 0:
            raise ValueError(f"run.workers must be >= 0 (0 = all cores), got {self.workers}")


@dataclass
class Config:
    env: EnvConfig = field(default_factory=EnvConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    run: RunConfig = field(default_factory=RunConfig)
    agent: AgentConfig = field(default_factory=AgentConfig)


# ---------------------------------------------------------------- validation (pydantic)
# The config sections are plain dataclasses owned by their packages (envs, mapping, agent, ...);
# pydantic validates a nested dict against them (types, Literal choices, finite numbers, then
# each section's own __post_init__ range checks) and ``_config_error`` turns its first error into
# calnav's one line naming the key and the valid keys or choices. The validation settings are
# attached here, once per dataclass, so the packages stay free of pydantic.
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
            tp = hints.get(item)
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


def _prepare(cls: type, data: dict, prefix: str) -> dict:
    """What pydantic's lax mode would read differently from calnav's configs: a ``WxH`` string
    for a size (2-tuple) field is split, and true / false for a number is refused (pydantic
    would take it as 1 / 0)."""
    hints, out = typing.get_type_hints(cls), dict(data)
    for name, value in data.items():
        tp, key = hints.get(name), f"{prefix}.{name}" if prefix else name
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


def _yaml_text(value: Any) -> str:
    """``value`` as YAML writes it (null, true, 3, [1, 2]), for messages."""
    return yaml.safe_dump(value, default_flow_style=True).strip().removesuffix("...").strip()


def _check_sections(cls: type, tree: dict, source: str, prefix: str = "") -> None:
    """Every key of ``tree`` (a YAML file's nested dict) naming a section of ``cls`` (a
    dataclass field) holds a mapping: ``env:`` left empty or ``env: null`` is named as the
    section it is, not as the first override that would be set under it."""
    hints = typing.get_type_hints(cls)
    for name, value in tree.items():
        tp = hints.get(name) if isinstance(name, str) else None
        if tp is None or not dataclasses.is_dataclass(tp):
            continue
        key = f"{prefix}.{name}" if prefix else name
        if not isinstance(value, dict):
            raise ConfigError(f"{source}: {key}: expected a mapping of {tp.__name__} keys, got {_yaml_text(value)}; "
                              f"write the keys under '{name}:' or delete the section")
        _check_sections(tp, value, source, key)


def _set_dotted(tree: dict, dotted: str, value: Any) -> None:
    parts = dotted.split(".")
    node = tree
    for p in parts[:-1]:
        node = node.setdefault(p, {})
        if not isinstance(node, dict):
            raise ConfigError(f"cannot override '{dotted}': '{p}' is not a section")
    node[parts[-1]] = value


def parse_override(text: str) -> tuple[str, Any]:
    """'a.b=value' -> ('a.b', parsed YAML scalar/list)."""
    if "=" not in text:
        raise ConfigError(f"override {text!r} must look like key.subkey=value")
    key, raw = text.split("=", 1)
    if not key:
        raise ConfigError(f"override {text!r} has an empty key")
    if not raw.strip():
        return key.strip(), ""
    return key.strip(), load_yaml_text(raw, f"override {text!r}")


def load_config(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = (),
                cls: type = Config) -> Any:
    """YAML file (optional) + dotted overrides -> validated config dataclass."""
    tree: dict = {}
    if path is not None:
        path = Path(path)
        if not path.exists() and (CONFIG_DIR / path.name).exists():
            path = CONFIG_DIR / path.name
        if not path.exists():
            raise ConfigError(f"config file not found: {path}")
        if path.is_dir():
            raise ConfigError(f"config {path} is a directory; give a YAML file, e.g. {CONFIG_DIR.name}/objectnav.yaml")
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError as exc:
            raise ConfigError(f"config {path} is not a UTF-8 YAML text file (byte {exc.start}: "
                              f"{exc.object[exc.start:exc.start + 1]!r})") from None
        except OSError as exc:
            raise ConfigError(f"cannot read config {path}: {exc.strerror or exc}") from None
        loaded = load_yaml_text(text, str(path)) or {}
        if not isinstance(loaded, dict):
            raise ConfigError(f"config file {path} must hold a mapping at the top level")
        _check_sections(cls, loaded, str(path))   # before an override is set under a null section
        tree = loaded
    for text in overrides:
        key, value = parse_override(text)
        _set_dotted(tree, key, value)
    return build_dataclass(cls, tree)


def with_shorthand(overrides: list[str], key: str, value: Any, option: str) -> list[str]:
    """``overrides`` plus ``key=value`` from a command-line shorthand (``--agent`` for
    ``run.agent``...). The same key also given as an override is refused rather than silently
    overridden by the shorthand: one line naming both."""
    for text in overrides:
        if text.partition("=")[0].strip() == key:
            raise ConfigError(f"{option} {value} and the override {text} both set {key}: give one of them")
    return [*overrides, f"{key}={value}"]


def expand_multirun(overrides: list[str]) -> list[list[str]]:
    """['a=1,2', 'b=x'] -> [['a=1', 'b=x'], ['a=2', 'b=x']] (cross product of comma lists).
    Values that are YAML lists ('[1,2]') are not split."""
    choices = []
    for text in overrides:
        key, _, raw = text.partition("=")
        if raw.startswith("[") or "," not in raw:
            choices.append([text])
        else:
            choices.append([f"{key}={v}" for v in raw.split(",")])
    return [list(c) for c in itertools.product(*choices)]


def to_dict(cfg: Any) -> dict:
    """Plain nested dict (tuples as lists) for YAML/JSON output."""
    def conv(v):
        if dataclasses.is_dataclass(v):
            return {f.name: conv(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (list, tuple)):
            return [conv(x) for x in v]
        if isinstance(v, dict):
            return {k: conv(x) for k, x in v.items()}
        return v
    return conv(cfg)


def dump_yaml(cfg: Any) -> str:
    return yaml.safe_dump(to_dict(cfg), sort_keys=False)
