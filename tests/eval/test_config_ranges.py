"""Declared ranges of the config keys (``common.ranges``): every size-like key (cells, voxels,
resolutions, map sizes, radii, heights, distances) of every config dataclass refuses values too
small and too large to mean anything, in one line naming the key, before anything is written;
cross-key constraints are checked at load with both keys named; a null section is named as one."""
from __future__ import annotations

import dataclasses

import pytest

from calnav.common.ranges import Range
from calnav.eval.cli import main
from calnav.eval.config import CONFIG_DIR, ConfigError, load_config

SMALL = ["env.resolution=32x24", "env.dataset.val_scenes=2", "env.dataset.episodes_per_scene=3"]

# (config file, override, what the message says); each key both too small and too large
OUT_OF_RANGE = [
    ("objectnav", "env.nav_cell_m=1e-9", "env.nav_cell_m must be in [0.005, 0.5] metres, got 1e-09"),
    ("objectnav", "env.nav_cell_m=1e6", "env.nav_cell_m must be in [0.005, 0.5] metres"),
    ("objectnav", "env.camera_height_m=0.001", "env.camera_height_m must be in [0.05, 3] metres"),
    ("objectnav", "env.camera_height_m=50", "env.camera_height_m must be in [0.05, 3] metres"),
    ("objectnav", "env.agent_radius_m=0.001", "env.agent_radius_m must be in [0.02, 1] metres"),
    ("objectnav", "env.agent_radius_m=50", "env.agent_radius_m must be in [0.02, 1] metres"),
    ("objectnav", "env.agent_height_m=0.01", "env.agent_height_m must be in [0.1, 3] metres"),
    ("objectnav", "env.agent_height_m=30", "env.agent_height_m must be in [0.1, 3] metres"),
    ("objectnav", "env.forward_step_m=1e-4", "env.forward_step_m must be in [0.01, 2] metres"),
    ("objectnav", "env.forward_step_m=20", "env.forward_step_m must be in [0.01, 2] metres"),
    ("objectnav", "env.max_depth_m=1e5", "env.max_depth_m must be in (0, 100] metres"),
    ("objectnav", "env.success_distance_m=0", "env.success_distance_m must be in (0, 10] metres"),
    ("objectnav", "env.view_point_radius_m=1e3", "env.view_point_radius_m must be in (0, 10] metres"),
    ("objectnav", "env.dataset.max_geodesic_m=1e9", "env.dataset.max_geodesic_m must be in (0, 1000] metres"),
    ("objectnav", "env.dataset.min_geodesic_m=-1", "env.dataset.min_geodesic_m must be in [0, 1000] metres"),
    ("objectnav", "env.dataset.min_island_radius_m=1e3", "env.dataset.min_island_radius_m must be in [0, 100]"),
    ("objectnav", "env.dataset.episodes_per_scene=0", "env.dataset.episodes_per_scene must be in [1, 10000]"),
    ("objectnav", "env.dataset.test_scenes=-1", "env.dataset.test_scenes must be in [0, 1000000] houses"),
    ("objectnav", "mapping.voxel_size_m=1e-6", "mapping.voxel_size_m must be in [0.005, 0.5] metres, got 1e-06"),
    ("objectnav", "mapping.voxel_size_m=1e3", "mapping.voxel_size_m must be in [0.005, 0.5] metres"),
    ("objectnav", "mapping.block_resolution=1", "mapping.block_resolution must be in [2, 32] voxels"),
    ("objectnav", "mapping.block_resolution=1024", "mapping.block_resolution must be in [2, 32] voxels"),
    ("objectnav", "mapping.trunc_voxels=0.01", "mapping.trunc_voxels must be in [1, 32] voxels"),
    ("objectnav", "mapping.depth_max_m=1e4", "mapping.depth_max_m must be in (0, 100] metres"),
    ("objectnav", "mapping.surface_band_voxels=1e4", "mapping.surface_band_voxels must be in (0, 64] voxels"),
    ("objectnav", "agent.cell_m=1e-9", "agent.cell_m must be in [0.01, 0.5] metres, got 1e-09"),
    ("objectnav", "agent.cell_m=1e6", "agent.cell_m must be in [0.01, 0.5] metres"),
    ("objectnav", "agent.map_size_m=0.1", "agent.map_size_m must be in [2, 200] metres"),
    ("objectnav", "agent.map_size_m=1e9", "agent.map_size_m must be in [2, 200] metres"),
    ("objectnav", "agent.agent_radius_m=1e3", "agent.agent_radius_m must be in [0.02, 1] metres"),
    ("objectnav", "agent.goal_dilation_m=1e3", "agent.goal_dilation_m must be in (0, 10] metres"),
    ("objectnav", "agent.collision_mark_length_m=-1", "agent.collision_mark_length_m must be in [0, 2] metres"),
    ("objectnav", "agent.collision_mark_width_m=1e3", "agent.collision_mark_width_m must be in [0, 2] metres"),
    ("objectnav", "agent.obstacle_min_height_m=10", "agent.obstacle_min_height_m must be in [0, 3] metres"),
    ("objectnav", "agent.map_resolution=8192x8192", "agent.map_resolution must be between 8x8 and 4096x4096"),
    ("calibrate_map", "scan.step_m=0", "scan.step_m must be in (0, 2] metres"),
    ("calibrate_map", "scan.step_m=5", "scan.step_m must be in (0, 2] metres"),
    ("calibrate_map", "scan.stop_spacing_m=1e3", "scan.stop_spacing_m must be in [0, 20] metres"),
    ("calibrate_map", "study.figure_resolution=10000x10000", "study.figure_resolution must be between 8x8"),
    ("calibrate_map", "sequence.label_distance_m=50", "sequence.label_distance_m must be in (0, 1] metres"),
    ("segmenter", "data.resolution=9000x9000", "data.resolution must be between 16x16 and 4096x4096"),
    ("train_predictor", "predictor_train.epochs=0", "predictor_train.epochs must be in [1, 1000] epochs, got 0"),
    ("train_predictor", "predictor_train.epochs=100000", "predictor_train.epochs must be in [1, 1000] epochs"),
    ("train_predictor", "predictor_train.pos_weight=0.5", "predictor_train.pos_weight must be in [1, 1000], got 0.5"),
    ("train_predictor", "predictor_train.pos_weight=1e6", "predictor_train.pos_weight must be in [1, 1000]"),
    ("train_predictor", "predictor_train.val_fraction=0", "predictor_train.val_fraction must be in (0, 1), got 0"),
    ("train_predictor", "predictor_train.val_fraction=1", "predictor_train.val_fraction must be in (0, 1), got 1"),
    ("train_predictor", "predictor_train.batch_size=0", "predictor_train.batch_size must be in [1, 1024] maps"),
    ("train_predictor", "predictor_train.batch_size=4096", "predictor_train.batch_size must be in [1, 1024] maps"),
    ("train_predictor", "predictor_train.lr=0", "predictor_train.lr must be in (0, 1], got 0"),
    ("train_predictor", "predictor_train.lr=10", "predictor_train.lr must be in (0, 1], got 10"),
]


def _sections(name: str) -> tuple[str, ...]:
    """The root config's sections of the commands a shipped config file is for."""
    from calnav.eval.config import (CALIBRATION_SECTIONS, EPISODE_SECTIONS, MAP_SECTIONS, PREDICTOR_SECTIONS,
                                    SEGMENTER_SECTIONS)

    return {"objectnav": EPISODE_SECTIONS, "calibrate_map": CALIBRATION_SECTIONS, "segmenter": SEGMENTER_SECTIONS,
            "map_sequence": MAP_SECTIONS, "demo": EPISODE_SECTIONS, "train_predictor": PREDICTOR_SECTIONS}[name]


@pytest.mark.parametrize("config,override,message", OUT_OF_RANGE, ids=[o for _, o, _ in OUT_OF_RANGE])
def test_size_keys_refuse_values_too_small_and_too_large(config, override, message):
    path = None if config == "train_predictor" else CONFIG_DIR / f"{config}.yaml"   # no file: the section's defaults
    with pytest.raises(ConfigError) as err:
        load_config(path, [override], sections=_sections(config))
    assert message in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("config", ["objectnav", "calibrate_map", "segmenter", "map_sequence", "demo"])
def test_the_shipped_configs_lie_in_range(config):
    load_config(CONFIG_DIR / f"{config}.yaml", [], sections=_sections(config))


def test_every_declared_range_names_a_key_of_its_section():
    from calnav.agent.config import AGENT_RANGES, AgentConfig
    from calnav.envs.config import DATASET_RANGES, ENV_RANGES, DatasetConfig, EnvConfig
    from calnav.envs.trajectories import SCAN_RANGES, ScanConfig
    from calnav.mapping.config import MAPPING_RANGES, MappingConfig
    from calnav.mapping.sequences.readers import SEQUENCE_RANGES, SequenceConfig
    from calnav.eval.sections import PREDICTOR_TRAIN_RANGES, PredictorTrainConfig

    for table, cls in ((AGENT_RANGES, AgentConfig), (ENV_RANGES, EnvConfig), (DATASET_RANGES, DatasetConfig),
                       (SCAN_RANGES, ScanConfig), (MAPPING_RANGES, MappingConfig), (SEQUENCE_RANGES, SequenceConfig),
                       (PREDICTOR_TRAIN_RANGES, PredictorTrainConfig)):
        names = {f.name for f in dataclasses.fields(cls)}
        assert set(table) <= names, (cls.__name__, set(table) - names)
        defaults = cls()
        assert all(rng.contains(getattr(defaults, key)) for key, rng in table.items()), cls.__name__


def test_range_refuses_nan_inf_and_bool():
    rng = Range(0.0, 1.0, "metres", lo_open=True)
    assert rng.contains(0.5) and rng.contains(1) and not rng.contains(0.0)
    for bad in (float("nan"), float("inf"), True, "0.5", None):
        assert not rng.contains(bad)
    with pytest.raises(ValueError, match=r"^x must be in \(0, 1\] metres, got nan$"):
        rng.check("x", float("nan"))


def test_scene_count_bound_is_the_split_block():
    from calnav.envs.config import MAX_SCENES_PER_SPLIT
    from calnav.envs.scenes import SPLIT_BLOCK

    assert MAX_SCENES_PER_SPLIT == SPLIT_BLOCK


@pytest.mark.parametrize("overrides,message", [
    (["env.dataset.max_geodesic_m=0.5"], "env.dataset.max_geodesic_m (0.5 m) must be above "
                                          "env.dataset.min_geodesic_m (1 m)"),
    (["env.dataset.min_geodesic_m=5", "env.dataset.max_geodesic_m=5"], "must be above env.dataset.min_geodesic_m"),
    (["env.dataset.val_scenes=0"], "env.split=val has no houses: env.dataset.val_scenes is 0"),
    (["env.split=test", "env.dataset.test_scenes=0"], "env.split=test has no houses: env.dataset.test_scenes is 0"),
])
def test_cross_key_constraints_name_both_keys_at_load(overrides, message):
    with pytest.raises(ConfigError) as err:
        load_config(None, overrides)
    assert message in str(err.value)
    load_config(None, ["env.dataset.val_scenes=0", "env.split=train"])   # another split's count may be 0


@pytest.mark.parametrize("text,section,got", [
    ("env: null\n", "env", "null"), ("env:\n", "env", "null"), ("run: null\n", "run", "null"),
    ("env:\n  dataset: null\n", "env.dataset", "null"), ("env: 3\n", "env", "3"),
    ("agent: [1, 2]\n", "agent", "[1, 2]"),
])
def test_a_null_section_is_named_as_a_section(tmp_path, text, section, got):
    path = tmp_path / "c.yaml"
    path.write_text(text)
    for overrides in ([], ["run.agent=oracle"], ["env.split=val"]):   # --agent adds run.agent=...
        with pytest.raises(ConfigError) as err:
            load_config(path, overrides)
        text = str(err.value)
        assert text.startswith(f"{path}: {section}: expected a mapping of ") and f"got {got};" in text


@pytest.mark.e2e
@pytest.mark.parametrize("override", ["agent.cell_m=1e6", "mapping.voxel_size_m=1e-6", "env.nav_cell_m=1e-9"])
def test_out_of_range_sizes_write_nothing(tmp_path, capsys, override):
    out = tmp_path / "run"
    assert main(["objectnav", "--episodes", "0:1", "--output", str(out), *SMALL, override]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "must be in [" in err[0] and override.split("=")[0] in err[0]
    assert not out.exists()


@pytest.mark.e2e
def test_a_reversed_episode_range_is_called_empty_or_reversed(tmp_path, capsys):
    for spec in ("5:2", "3:3"):
        args = ["objectnav", "--agent", "oracle", "--episodes", spec, "--output", str(tmp_path / "r"), *SMALL]
        assert main(args) == 2
        err = capsys.readouterr().err
        assert f"episode range '{spec}' is empty or reversed" in err and "outside the split" not in err
    assert not (tmp_path / "r").exists()


@pytest.mark.e2e
def test_collision_threshold_must_be_below_the_forward_step(tmp_path, capsys):
    out = tmp_path / "r"
    assert main(["objectnav", "--episodes", "0:1", "--output", str(out), *SMALL, "env.forward_step_m=0.15"]) == 2
    assert ("agent.collision_min_move_m (0.2 m) must be below env.forward_step_m (0.15 m)"
            in capsys.readouterr().err)
    assert not out.exists()


@pytest.mark.parametrize("splits,message", [
    ("", "--splits '' names no split; give a comma-separated list of: train, val, test, calib"),
    (",", "--splits ',' names no split"),
    ("val,vall", "--splits: unknown split 'vall'; valid splits: train, val, test, calib"),
    ("test", "--splits test: env.dataset.test_scenes is 0, so the split has no houses to scan"),
])
def test_scan_houses_refuses_split_lists_without_houses(tmp_path, capsys, splits, message):
    out = tmp_path / "scan"
    assert main(["scan-houses", "--splits", splits, "--output", str(out), "env.dataset.test_scenes=0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not out.exists()
