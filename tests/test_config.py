"""Typed YAML config with dotted overrides: values, errors naming key and choices, multirun."""
import pytest

from eval.config import (CONFIG_DIR, Config, ConfigError, dump_yaml, expand_multirun, load_config,
                         parse_override)


def test_defaults_and_dotted_overrides():
    cfg = load_config(None, ["env.resolution=160x120", "env.split=test", "run.seed=3",
                             "env.dataset.val_scenes=2", "env.semantic_sensor=false"])
    assert isinstance(cfg, Config)
    assert cfg.env.resolution == (160, 120)
    assert cfg.env.split == "test" and cfg.run.seed == 3 and cfg.env.dataset.val_scenes == 2
    assert cfg.env.semantic_sensor is False
    assert cfg.env.hfov_deg == 79.0  # untouched default


def test_every_shipped_config_loads():
    from eval.calibration.config import CalibrateMapConfig
    from eval.segmenter.data import SegmenterExperimentConfig

    # experiments with their own schema
    special = {"segmenter.yaml": SegmenterExperimentConfig, "calibrate_map.yaml": CalibrateMapConfig}
    # habitat-lab configs (habitat_*.yaml) are hydra configs of habitat-lab's schema: composed
    # by habitat-lab in tests/test_habitat.py
    files = sorted(p for p in CONFIG_DIR.glob("*.yaml") if not p.name.startswith("habitat_"))
    assert files
    for path in files:
        load_config(path, cls=special.get(path.name, Config))


def test_unknown_key_names_valid_keys():
    with pytest.raises(ConfigError, match=r"unknown config key 'env.resolutio'.*valid keys under 'env':.*resolution"):
        load_config(None, ["env.resolutio=160x120"])
    with pytest.raises(ConfigError, match=r"unknown config key 'nope'.*top level"):
        load_config(None, ["nope=1"])


def test_bad_values_name_key_and_choices():
    with pytest.raises(ConfigError, match=r"env.split.*'vall'.*valid choices: train, val, test"):
        load_config(None, ["env.split=vall"])
    with pytest.raises(ConfigError, match=r"env.hfov_deg.*expected a number"):
        load_config(None, ["env.hfov_deg=wide"])
    with pytest.raises(ConfigError, match=r"env.max_episode_steps.*expected an integer"):
        load_config(None, ["env.max_episode_steps=1.5x"])
    with pytest.raises(ConfigError, match=r"resolution must be at least 8x8"):
        load_config(None, ["env.resolution=4x4"])
    with pytest.raises(ConfigError, match=r"expected true or false"):
        load_config(None, ["env.enable_look=maybe"])


def test_override_syntax_errors():
    with pytest.raises(ConfigError, match="key.subkey=value"):
        parse_override("env.split")
    with pytest.raises(ConfigError, match="not a section"):
        load_config(None, ["run.seed=1", "run.seed.x=2"])


def test_missing_file_is_clear(tmp_path):
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "missing.yaml")


def test_yaml_round_trip(tmp_path):
    cfg = load_config(None, ["env.resolution=160x120", "mapping.fusion=rbu"])
    path = tmp_path / "c.yaml"
    path.write_text(dump_yaml(cfg))
    assert load_config(path) == cfg


def test_multirun_cross_product():
    runs = expand_multirun(["mapping.fusion=rbu,averaging", "env.split=val", "x=[1,2]"])
    assert runs == [["mapping.fusion=rbu", "env.split=val", "x=[1,2]"],
                    ["mapping.fusion=averaging", "env.split=val", "x=[1,2]"]]
