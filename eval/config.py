"""Typed configuration: one root config (``Config``) of every command, loaded from YAML, with
dotted CLI overrides.

``load_config("configs/objectnav.yaml", ["env.resolution=160x120", "mapping.fusion=glfs"])``
returns a ``Config``; an unknown key or a bad value raises ``ConfigError`` naming the key and
the valid keys / choices. Every section's defaults live in its package's dataclass, so a YAML
file only states what it changes. A command uses some of the sections (``sections``; the
command declarations ``eval.parser.COMMANDS`` name them per command): those are filled, a file or
override setting another is refused, the rest stay None. Keys that moved (``MOVED_KEYS``) are
read at their new place wherever a config is read (a file, an override, a results directory's
stored ``config.yaml``).
"""
from __future__ import annotations

import copy
import dataclasses
import itertools
import sys
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from calnav.common.yaml_keys import unique_key_loader
from calnav.agent.config import AgentConfig
from calnav.agent.registry import AGENTS
from calnav.agent.segmenters.base import SegmenterConfig
from calnav.agent.setup import AgentSetup, SensorSetup
from calnav.envs.config import EnvConfig
from calnav.envs.trajectories import ScanConfig
from calnav.mapping.calibration.glfs_config import GLFSTrainConfig
from calnav.mapping.config import MappingConfig
from calnav.mapping.sequences import SequenceConfig
from calnav.eval.backends import BACKENDS
from calnav.eval.validation import WXH_RE, ConfigError, build_dataclass, section_type  # noqa: F401 (re-exported)
from calnav.eval.sections import (CalibrationStudyConfig, PredictorTrainConfig, SegDataConfig, SequenceSetConfig,
                                  TrainConfig)

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"


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




@dataclass
class RunConfig:
    """How an experiment runs, and which agent runs it (``agent.registry.AGENTS``)."""

    agent: str = "peanut"         # agent that runs the episodes (agent.registry.AGENTS): peanut (semantic map, agent.*) | oracle (shortest path)
    seed: int = 0                 # master random seed
    workers: int = 0              # parallel worker processes; 0 = all cores (backend ray: 0 = no cap on tasks in flight)
    backend: str = "local"        # where work items run (eval.backends.BACKENDS): local (this machine's cores) | ray
    ray_address: str = ""         # backend ray: "" = start a local Ray instance; "auto" or "ray://host:port" = join a cluster
    output_dir: str = "runs/latest"  # where results, plots and videos go
    device: str = "cpu"           # torch device for learned models ("cpu", "cuda", "cuda:1")

    def __post_init__(self) -> None:
        if self.workers < 0:
            raise ValueError(f"run.workers must be >= 0 (0 = all cores), got {self.workers}")
        AGENTS.check(self.agent)   # the name only: the agent loads when it is built
        BACKENDS.check(self.backend)


@dataclass
class Config:
    """The root config of every command: one section per package dataclass. A command uses some
    of them (``load_config``'s ``sections``): those hold their values, the others are None, so a
    dumped config (``config.yaml``) holds exactly the command's sections."""

    env: EnvConfig | None = None                  # simulator, sensors, houses and episodes (envs.config)
    mapping: MappingConfig | None = None          # the 3D semantic map and its fusion (mapping.config)
    run: RunConfig | None = None                  # how the experiment runs (above)
    agent: AgentConfig | None = None              # the ObjectNav agent (agent.config); agent.segmenter: which segmenter
    segmenter: SegmenterConfig | None = None      # the segmenter's settings, for every command (agent.segmenters.base)
    scan: ScanConfig | None = None                # calibration scans of houses (envs.trajectories)
    study: CalibrationStudyConfig | None = None   # the map-calibration study (eval.sections)
    glfs: GLFSTrainConfig | None = None           # GLFS training (mapping.calibration.glfs_config)
    sequences: SequenceSetConfig | None = None    # recorded sequences instead of houses (eval.sections)
    sequence: SequenceConfig | None = None        # how a recorded sequence is read (mapping.sequences)
    data: SegDataConfig | None = None             # frames a segmenter trains / is scored on (eval.sections)
    train: TrainConfig | None = None              # a segmenter's training (eval.sections)
    predictor_train: PredictorTrainConfig | None = None  # the target predictor's training (eval.sections)

    def __post_init__(self) -> None:
        if self.study is not None and self.glfs is not None:
            self.glfs_configs()    # a bad GLFS variant is refused at load time, before anything is written

    @property
    def sections(self) -> tuple[str, ...]:
        """The sections this config holds (the command's), in field order."""
        return tuple(f.name for f in dataclasses.fields(self) if getattr(self, f.name) is not None)

    def glfs_configs(self) -> dict[str, GLFSTrainConfig]:
        """{variant name: the ``glfs`` section with the variant's overrides} (``study.glfs_variants``)."""
        base = to_dict(self.glfs)
        return {v.name: build_dataclass(GLFSTrainConfig, {**base, **v.overrides},
                                        prefix=f"study.glfs_variants.{v.name}.overrides")
                for v in self.study.glfs_variants}


def agent_setup(cfg: Config, agent: str = "") -> AgentSetup:
    """The agent's typed setup (``agent.setup.AgentSetup``) of a root config holding the episode
    sections (``EPISODE_SECTIONS``): its agent, segmenter and mapping sections as they are, the
    env's facts the agent may know, ``run.device``; ``agent``: the ``run.agent`` to build ("" =
    ``cfg.run.agent``). The one place a command's config becomes the agent's."""
    env = cfg.env
    sensor = SensorSetup(tuple(env.resolution), env.hfov_deg, env.camera_height_m, env.min_depth_m, env.max_depth_m,
                         env.normalize_depth, env.forward_step_m, env.turn_angle_deg, env.view_point_radius_m,
                         env.max_episode_steps, env.dataset.storeys)
    return AgentSetup(cfg.agent, cfg.segmenter, cfg.mapping, sensor, agent or cfg.run.agent, cfg.run.device)


SECTIONS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(Config))
# The sections a kind of command uses (``eval.parser.COMMANDS``: each command's ``Command.sections``):
EPISODE_SECTIONS: tuple[str, ...] = ("env", "mapping", "run", "agent", "segmenter")   # ObjectNav episodes (the default)
CALIBRATION_SECTIONS: tuple[str, ...] = ("env", "mapping", "run", "segmenter", "scan", "study", "glfs", "sequences",
                                         "sequence")   # calibrate-map, fit-glfs, export-sequence
SEGMENTER_SECTIONS: tuple[str, ...] = ("env", "run", "segmenter", "data", "train")   # train- / eval-segmenter
MAP_SECTIONS: tuple[str, ...] = ("mapping", "run", "segmenter", "sequence")   # calnav map
PREDICTOR_SECTIONS: tuple[str, ...] = ("predictor_train",)   # train-predictor

# ---------------------------------------------------------------- moved keys
# Keys that moved, old dotted key -> new dotted key (a section or a key). Every config read --
# a user's file or override (with a one-line note on stderr naming the new key), a results
# directory's stored config.yaml (``eval.results_dir``, ``calnav compare``) -- sees the new
# place, so a results directory written before a move resumes and compares as the same config.
MOVED_KEYS: dict[str, str] = {
    "agent.segmenter_config": "segmenter",   # the segmenter's settings: one top-level section for every command
}
# Command-line flags that were renamed, old -> new: refused in one line naming the new flag (a flag
# is typed, not stored, so nothing has to be read at the new place).
MOVED_FLAGS: dict[str, str] = {
    "--model": "--segmenter",   # the segmenter is spelled --segmenter on every command
}
_NOTED: set[tuple[str, str]] = set()   # (source, old key) already noted in this process
_ABSENT = object()


def _moved_from(dotted: str) -> str | None:
    """The moved key (``MOVED_KEYS``) that ``dotted`` is or lies under, or None."""
    return next((old for old in MOVED_KEYS if dotted == old or dotted.startswith(old + ".")), None)


def migrate_key(dotted: str) -> str:
    """``dotted`` at its new place when it is, or lies under, a moved key (``MOVED_KEYS``)."""
    old = _moved_from(dotted)
    return dotted if old is None else MOVED_KEYS[old] + dotted[len(old):]


def moved_flag(word: str) -> str | None:
    """The new spelling of a renamed flag (``MOVED_FLAGS``) that command-line word ``word`` is
    (``--model`` or ``--model=NAME``), or None."""
    return MOVED_FLAGS.get(word.partition("=")[0]) if word.startswith("--") else None


def _note_moved(source: str, old: str) -> None:
    """One note on stderr per source and moved key: where the key lives now."""
    if (source, old) not in _NOTED:
        _NOTED.add((source, old))
        print(f"calnav: note: {source}: {old} has moved to {MOVED_KEYS[old]} and is read there; write "
              f"{MOVED_KEYS[old]}", file=sys.stderr)


def _pop_dotted(tree: dict, dotted: str, pop: bool = True) -> Any:
    """The value at ``dotted`` in ``tree`` (removed unless not ``pop``), or ``_ABSENT``."""
    *parents, last = dotted.split(".")
    node = tree
    for p in parents:
        node = node.get(p) if isinstance(node, dict) else None
    if not isinstance(node, dict):
        return _ABSENT
    return node.pop(last, _ABSENT) if pop else node.get(last, _ABSENT)


def migrate_tree(tree: dict, source: str = "") -> dict:
    """A copy of ``tree`` (a nested config dict) with every moved key at its new place; one
    ``source`` (a user's file) gets a note on stderr per moved key, a stored one (``source``
    "") none. A key written at both places is a ConfigError naming both."""
    out = copy.deepcopy(tree)
    for old, new in MOVED_KEYS.items():
        value = _pop_dotted(out, old)
        if value is _ABSENT:
            continue
        if _pop_dotted(out, new, pop=False) is not _ABSENT:
            raise ConfigError(f"{source or 'config'}: {old} and {new} are one setting ({old} moved to {new}); "
                              f"write only {new}")
        _set_dotted(out, new, value)
        if source:
            _note_moved(source, old)
    return out


def _yaml_text(value: Any) -> str:
    """``value`` as YAML writes it (null, true, 3, [1, 2]), for messages."""
    return yaml.safe_dump(value, default_flow_style=True).strip().removesuffix("...").strip()


def _check_sections(cls: type, tree: dict, source: str, prefix: str = "") -> None:
    """Every key of ``tree`` (a YAML file's nested dict) naming a section of ``cls`` (a
    dataclass field) holds a mapping: ``env:`` left empty or ``env: null`` is named as the
    section it is, not as the first override that would be set under it."""
    hints = typing.get_type_hints(cls)
    for name, value in tree.items():
        tp = section_type(hints.get(name)) if isinstance(name, str) else None
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


def _who(command: str) -> str:
    return f"calnav {command}" if command else "this command"


def _check_used(names, sections: tuple[str, ...], command: str, source: str) -> None:
    """Every top-level key of ``names`` is one of ``sections`` (the command's): a section the
    command does not use, or no section at all, is a one-line ConfigError naming them."""
    for name in names:
        if name in sections:
            continue
        if name in SECTIONS:
            raise ConfigError(f"{source} sets the '{name}' section, which {_who(command)} does not use; its sections: "
                              f"{', '.join(sections)}")
        raise ConfigError(f"unknown config key '{name}'; valid keys at the top level: {', '.join(sections)}")


def load_config(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = (),
                cls: type = Config, sections: tuple[str, ...] = EPISODE_SECTIONS, command: str = "") -> Any:
    """YAML file (optional) + dotted overrides -> validated config dataclass. For the root
    ``Config``: moved keys are read at their new place (``MOVED_KEYS``, with a note), only
    ``sections`` (the command's, ``command`` for messages) may be set, and they are filled
    with their defaults; ``cls``: another dataclass read the same way (a study's plan file)."""
    root = cls is Config
    tree: dict = {}
    if path is not None:
        path = Path(path)
        if not path.exists() and (CONFIG_DIR / path.name).exists():
            path = CONFIG_DIR / path.name
        if not path.exists():
            shipped = ", ".join(sorted(f.name for f in CONFIG_DIR.glob("*.yaml")))
            raise ConfigError(f"config file not found: {path}; the shipped configs (found by name too): {shipped}")
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
        if root:
            loaded = migrate_tree(loaded, str(path))
            _check_used(loaded, sections, command, str(path))
        _check_sections(cls, loaded, str(path))   # before an override is set under a null section
        tree = loaded
    for text in overrides:
        key, value = parse_override(text)
        if root:
            old = _moved_from(key)
            if old is not None:
                _note_moved(f"override {text}", old)
                key = migrate_key(key)
            _check_used([key.split(".")[0]], sections, command, f"the override {text}")
        _set_dotted(tree, key, value)
    if root:
        for name in sections:   # the command's sections, each at least its defaults
            value = tree.setdefault(name, {})
            if not isinstance(value, dict):
                tp = section_type(typing.get_type_hints(Config)[name])
                raise ConfigError(f"bad value for {name}: {_yaml_text(value)}; expected a mapping of "
                                  f"{tp.__name__} keys")
    return build_dataclass(cls, tree)


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
    """Plain nested dict (tuples as lists) for YAML/JSON output; of a root ``Config`` only the
    sections it holds (the command's)."""
    def conv(v):
        if dataclasses.is_dataclass(v):
            omit = getattr(type(v), "OMIT_AT_DEFAULT", {})   # (envs.config.plain_dict: older configs stay equal)
            return {f.name: conv(getattr(v, f.name)) for f in dataclasses.fields(v)
                    if not (f.name in omit and getattr(v, f.name) == omit[f.name])}
        if isinstance(v, (list, tuple)):
            return [conv(x) for x in v]
        if isinstance(v, dict):
            return {k: conv(x) for k, x in v.items()}
        return v
    if isinstance(cfg, Config):
        return {name: conv(getattr(cfg, name)) for name in cfg.sections}
    return conv(cfg)


def dump_yaml(cfg: Any) -> str:
    return yaml.safe_dump(to_dict(cfg), sort_keys=False)
