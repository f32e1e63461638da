"""Typed configuration: dataclasses loaded from YAML, with dotted CLI overrides.

``load_config("configs/objectnav.yaml", ["env.resolution=160x120", "mapping.fusion=glfs"])``
returns a ``Config``; an unknown key or a bad value raises ``ConfigError`` naming the key and
the valid keys / choices. Every section's defaults live in its package's dataclass, so a YAML
file only states what it changes.
"""
from __future__ import annotations

import dataclasses
import itertools
import math
import re
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Union

import yaml

from agent.config import AgentConfig
from envs.config import EnvConfig
from mapping.config import MappingConfig

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"


class ConfigError(ValueError):
    """A config key or value is invalid; the message names it and the valid choices."""


# "WxH" sizes (160x120). YAML 1.1 reads "0x0" / "0x10" as hexadecimal integers (0, 16), so the
# loader keeps text of this form a string and the tuple coercion splits it.
WXH_RE = re.compile(r"^\d+x\d+$")


class StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses a mapping key written twice (plain YAML keeps the last, silently
    dropping e.g. a whole section) and reads ``WxH`` as text, never as a hex integer."""

    def construct_mapping(self, node, deep=False):
        seen: dict = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            line = key_node.start_mark.line + 1
            try:
                duplicate = key in seen
            except TypeError:  # an unhashable key: SafeLoader's own error names it below
                continue
            if duplicate:
                raise ConfigError(f"duplicate key {key!r} at line {line} (first at line {seen[key]}); "
                                  "write each key once")
            seen[key] = line
        return super().construct_mapping(node, deep=deep)


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


# ---------------------------------------------------------------- coercion
def _describe(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    return getattr(tp, "__name__", str(tp))


def _coerce(value: Any, tp: Any, key: str) -> Any:
    """Convert a YAML/CLI value to type ``tp`` or raise ConfigError naming ``key``."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is Literal:
        if value not in args:
            raise ConfigError(f"bad value for {key}: {value!r}; valid choices: {', '.join(map(str, args))}")
        return value
    if origin in (Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(value, a, key)
            except ConfigError:
                pass  # try the next member; the error below names them all
        raise ConfigError(f"bad value for {key}: {value!r}; expected {' or '.join(_describe(a) for a in args)}")
    if origin is tuple:
        if isinstance(value, str) and "x" in value and len(args) == 2:  # "160x120"
            value = value.split("x")
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"bad value for {key}: {value!r}; expected a list (or 'WxH')")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], key) for v in value)
        if len(value) != len(args):
            raise ConfigError(f"bad value for {key}: {value!r}; expected {len(args)} items")
        return tuple(_coerce(v, a, key) for v, a in zip(value, args))
    if origin is list:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"bad value for {key}: {value!r}; expected a list")
        return [_coerce(v, args[0], key) for v in value]
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"bad value for {key}: {value!r}; expected a mapping")
        return {k: _coerce(v, args[1], f"{key}.{k}") for k, v in value.items()}
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"bad value for {key}: {value!r}; expected a mapping of {tp.__name__} keys")
        return build_dataclass(tp, value, key)
    if tp is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "false", "yes", "no", "1", "0"):
            return value.lower() in ("true", "yes", "1")
        raise ConfigError(f"bad value for {key}: {value!r}; expected true or false")
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, (int, str)):
            raise ConfigError(f"bad value for {key}: {value!r}; expected an integer")
        try:
            return int(value)
        except ValueError:
            raise ConfigError(f"bad value for {key}: {value!r}; expected an integer") from None
    if tp is float:
        if isinstance(value, bool):
            raise ConfigError(f"bad value for {key}: {value!r}; expected a number")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"bad value for {key}: {value!r}; expected a number") from None
        if not math.isfinite(number):   # by construction: no config key takes NaN or inf
            raise ConfigError(f"bad value for {key}: {value!r}; expected a finite number")
        return number
    if tp is str:
        if isinstance(value, (dict, list)):
            raise ConfigError(f"bad value for {key}: {value!r}; expected a string")
        return str(value)
    if tp is Any:
        return value
    raise ConfigError(f"{key}: unsupported config type {tp!r}")


def build_dataclass(cls: type, data: dict, prefix: str = "") -> Any:
    """Build ``cls`` from a (possibly partial) nested dict, validating every key and value."""
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    kwargs = {}
    for key, value in data.items():
        full = f"{prefix}.{key}" if prefix else key
        if key not in names:
            where = f"under '{prefix}'" if prefix else "at the top level"
            raise ConfigError(f"unknown config key '{full}'; valid keys {where}: {', '.join(names)}")
        kwargs[key] = _coerce(value, hints[key], full)
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (ValueError, TypeError) as exc:  # a section's own __post_init__ validation
        raise ConfigError(f"{prefix or cls.__name__}: {exc}") from exc


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
