"""calnav episodes as a habitat-lab ObjectNav dataset, and habitat-lab configs on calnav houses.

The dataset: ``load_split`` already writes habitat-lab's ObjectNav-v1 layout
(``<split_dir>/<split>.json.gz`` + ``content/<scene_id>.json.gz``); ``prepare_habitat_dataset``
adds ``calnav_env.json`` beside them, the ``EnvConfig`` the episodes were generated with (houses,
navigation grid, sensor geometry). With ``habitat.dataset.scenes_dir`` set to the split
directory, habitat-lab's loader turns each episode's ``scene_id`` into
``<split_dir>/<scene_id>``, and ``CalnavSim-v0`` finds the houses' description next to it.

Which settings come from where (``env_overrides_from_habitat``): habitat-lab's config owns
what it has a key for -- the sensor (resolution, hfov, camera height, depth range and
normalisation, semantic sensor on / off), the agent (radius, height), the motion (forward step, turn and tilt angles,
look actions on / off), the step limit, the success distance and the split; calnav's ``env``
section owns the rest (the houses: ``env.dataset.*``; the navigation grid; noise).
"""
from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path

from calnav.common.atomic import write_text_atomic
from calnav.envs.config import DatasetConfig, EnvConfig, NavMeshConfig, plain_dict
from calnav.envs.scanning.config import ScanningConfig
from calnav.envs.episodes import dataset_key, load_split, split_dir

DESCRIPTOR = "calnav_env.json"          # beside <split>.json.gz: the EnvConfig of the episodes
DESCRIPTOR_FORMAT = "calnav-habitat-dataset"
DESCRIPTOR_VERSION = 2
AGENT = "main_agent"                     # habitat-lab's single-agent name
HABITAT_CONFIG = str(Path(__file__).resolve().parents[1] / "configs" / "habitat_objectnav.yaml")  # the default
# EnvConfig keys that habitat-lab's config sets (a calnav override of one of them is refused)
HABITAT_OWNED: tuple[str, ...] = (
    "split", "resolution", "hfov_deg", "camera_height_m", "min_depth_m", "max_depth_m", "normalize_depth", "semantic_sensor",
    "forward_step_m", "turn_angle_deg", "tilt_angle_deg", "enable_look", "agent_radius_m", "agent_height_m",
    "max_episode_steps", "success_distance_m")
SENSOR_TYPES = {"rgb": "HabitatSimRGBSensor", "depth": "HabitatSimDepthSensor",
                "semantic": "HabitatSimSemanticSensor"}


def sensor_configs(sim_cfg) -> dict[str, object]:
    """The main agent's sensor configs by kind (rgb / depth / semantic); ValueError on a sensor
    type calnav cannot render or on two sensors of one kind."""
    out: dict[str, object] = {}
    valid = {v: k for k, v in SENSOR_TYPES.items()}
    for name, s in sim_cfg.agents[AGENT].sim_sensors.items():
        if s.type not in valid:
            raise ValueError(f"habitat sensor {name} has type {s.type!r}, which CalnavSim-v0 cannot render; "
                             f"valid: {', '.join(SENSOR_TYPES.values())}")
        kind = valid[s.type]
        if kind in out:
            raise ValueError(f"habitat config has two {kind} sensors; CalnavSim-v0 renders one of each")
        out[kind] = s
    if "rgb" not in out and "depth" not in out:
        raise ValueError("habitat config has neither an rgb nor a depth sensor")
    return out


def env_overrides_from_sim(sim_cfg) -> dict:
    """EnvConfig fields set by habitat-lab's simulator config (``habitat.simulator``)."""
    sensors = sensor_configs(sim_cfg)
    first = sensors.get("rgb", sensors.get("depth"))
    for kind, s in sensors.items():  # one camera renders every sensor
        for key in ("width", "height", "hfov", "position", "orientation"):
            if _as_list(s[key]) != _as_list(first[key]):
                raise ValueError(f"habitat {kind} sensor {key}={_as_list(s[key])} differs from "
                                 f"{_as_list(first[key])}: CalnavSim-v0 renders all sensors from one camera")
    if any(float(v) != 0.0 for v in first.orientation):
        raise ValueError(f"habitat sensor orientation must be [0, 0, 0] (CalnavSim-v0 tilts only with look actions), "
                         f"got {list(first.orientation)}")
    agent = sim_cfg.agents[AGENT]
    out = {"resolution": (int(first.width), int(first.height)), "hfov_deg": float(first.hfov),
           "camera_height_m": float(first.position[1]), "semantic_sensor": "semantic" in sensors,
           "forward_step_m": float(sim_cfg.forward_step_size), "turn_angle_deg": float(sim_cfg.turn_angle),
           "agent_radius_m": float(agent.radius), "agent_height_m": float(agent.height)}
    if "depth" in sensors:
        d = sensors["depth"]
        out.update(min_depth_m=float(d.min_depth), max_depth_m=float(d.max_depth), normalize_depth=bool(d.normalize_depth))
    return out


def _as_list(v):
    return list(v) if hasattr(v, "__iter__") and not isinstance(v, str) else v


def env_overrides_from_habitat(cfg) -> dict:
    """EnvConfig fields set by a whole habitat-lab config (``cfg.habitat`` or its root)."""
    h = cfg.habitat if "habitat" in cfg else cfg
    actions = h.task.actions
    out = env_overrides_from_sim(h.simulator)
    out.update(split=str(h.dataset.split), max_episode_steps=int(h.environment.max_episode_steps),
               success_distance_m=float(h.task.measurements.success.success_distance),
               enable_look="look_up" in actions and "look_down" in actions)
    if "look_up" in actions:
        out["tilt_angle_deg"] = float(actions.look_up.tilt_angle)
    return out


def env_config_from_habitat(cfg, base: EnvConfig | None = None) -> EnvConfig:
    """calnav's EnvConfig for a habitat-lab config: ``base`` (calnav's ``env`` section) with
    every habitat-owned field taken from ``cfg``."""
    env = replace(base or EnvConfig(), **env_overrides_from_habitat(cfg))
    EnvConfig.__post_init__(env)
    return env


# ------------------------------------------------------------------------------- dataset
def prepare_habitat_dataset(env_cfg: EnvConfig, progress: bool = True) -> Path:
    """Generate (if needed) ``env_cfg.split``'s episodes and write the descriptor; returns the
    split directory (habitat-lab's ``scenes_dir``; ``data_path`` is ``<dir>/{split}.json.gz``)."""
    load_split(env_cfg.split, env_cfg, progress=progress)  # also adds the iou key to old files
    root = split_dir(env_cfg.split, env_cfg)
    path = root / DESCRIPTOR
    text = json.dumps({"format": DESCRIPTOR_FORMAT, "version": DESCRIPTOR_VERSION, "env": plain_dict(env_cfg)},
                      indent=1, sort_keys=True)
    if not path.exists() or path.read_text() != text:
        write_text_atomic(path, text)
    return root


def read_descriptor(scene_path: str) -> tuple[EnvConfig, str]:
    """(EnvConfig of the episodes, calnav scene id) for a habitat ``scene_id`` path
    ``<split_dir>/<scene_id>``; ValueError when it is not a calnav scene."""
    p = Path(scene_path)
    desc = p.parent / DESCRIPTOR
    if not desc.exists():
        raise ValueError(f"scene {scene_path!r} is not a calnav scene: {desc} is missing (habitat.dataset.scenes_dir "
                         "must be a calnav split directory, from envs.habitat_config.prepare_habitat_dataset)")
    data = json.loads(desc.read_text())
    if data.get("format") != DESCRIPTOR_FORMAT or data.get("version") != DESCRIPTOR_VERSION:
        raise ValueError(f"{desc} is not a calnav {DESCRIPTOR_FORMAT} v{DESCRIPTOR_VERSION} file")
    env = dict(data["env"])
    ds = dict(env["dataset"])
    ds["scanning"] = ScanningConfig(**ds["scanning"])
    env_cfg = EnvConfig(**{**env, "resolution": tuple(env["resolution"]), "dataset": DatasetConfig(**ds),
                           "navmesh": NavMeshConfig(**env["navmesh"])})
    from calnav.envs.scenes import split_scene_ids

    valid = split_scene_ids(env_cfg.split, env_cfg.dataset)
    if p.name not in valid:
        raise ValueError(f"scene {p.name!r} is not a calnav scene of split {env_cfg.split!r} ({desc.parent}); "
                         f"valid: {', '.join(valid[:3])}{', ...' if len(valid) > 3 else ''}")
    return env_cfg, p.name


def check_same_episodes(episodes_env: EnvConfig, env: EnvConfig, where: str) -> None:
    """ValueError when ``env`` would not generate the episodes that ``episodes_env`` did (a
    habitat sensor / agent setting differs from the one the episode files were made with)."""
    if dataset_key(env) != dataset_key(episodes_env):
        diff = {k: (getattr(env, k), getattr(episodes_env, k)) for k in asdict(env)
                if k != "dataset" and getattr(env, k) != getattr(episodes_env, k)}
        raise ValueError(f"{where}: the habitat config does not match the episodes' settings "
                         f"(config, episodes): {diff}; regenerate with prepare_habitat_dataset")


# ------------------------------------------------------------------------------- config
def habitat_config(env_base: EnvConfig | None = None, overrides: list[str] | None = None,
                   config_path: str = HABITAT_CONFIG, progress: bool = True):
    """(habitat-lab config, calnav EnvConfig): ``config_path`` composed by habitat-lab with
    ``overrides`` (``habitat.*`` keys), its dataset pointed at calnav's episodes of the
    config's split (generated on first use). ``env_base``: calnav's ``env`` section for the
    calnav-owned settings. ValueError on an unknown habitat key."""
    from calnav.common.habitat_import import import_habitat

    habitat = import_habitat()
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    path = Path(config_path)
    if not path.exists() and (Path(HABITAT_CONFIG).parent / path.name).exists():
        path = Path(HABITAT_CONFIG).parent / path.name  # a file of calnav's configs/, from any directory
    if not path.exists():
        raise FileNotFoundError(f"habitat config {config_path} not found")
    for text in overrides or []:   # Hydra takes nan / inf as numbers; calnav's keys refuse them, so do these
        key, _, value = text.partition("=")
        if value.strip().lower().lstrip("+-.") in ("nan", "inf", "infinity"):
            raise ValueError(f"bad habitat config override {text}: {key} expects a finite number")
    try:
        cfg = habitat.get_config(str(path), overrides=list(overrides or []))
    except (HydraException, OmegaConfBaseException) as exc:
        first = str(exc).strip().splitlines()[0]
        raise ValueError(f"bad habitat config override: {first} (habitat keys: habitat.simulator.*, "
                         "habitat.task.*, habitat.environment.*, habitat.dataset.*)") from None
    env = env_config_from_habitat(cfg, env_base)
    root = prepare_habitat_dataset(env, progress=progress)
    with habitat.config.read_write(cfg):
        cfg.habitat.dataset.data_path = str(root / f"{env.split}.json.gz")
        cfg.habitat.dataset.scenes_dir = str(root)
    return cfg, env
