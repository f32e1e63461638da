"""Typed YAML config with dotted overrides: values, errors naming key and choices, multirun."""
import os

import pytest

from calnav.eval.config import (CALIBRATION_SECTIONS, CONFIG_DIR, MAP_SECTIONS, SEGMENTER_SECTIONS, Config,
                                ConfigError, dump_yaml, expand_multirun, load_config, parse_override)
from calnav.mapping.registry import LAYOUTS


def test_defaults_and_dotted_overrides():
    cfg = load_config(None, ["env.resolution=160x120", "env.split=test", "run.seed=3",
                             "env.dataset.val_scenes=2", "env.semantic_sensor=false"])
    assert isinstance(cfg, Config)
    assert cfg.env.resolution == (160, 120)
    assert cfg.env.split == "test" and cfg.run.seed == 3 and cfg.env.dataset.val_scenes == 2
    assert cfg.env.semantic_sensor is False
    assert cfg.env.hfov_deg == 79.0  # untouched default


def test_every_shipped_config_loads():
    from calnav.eval.objectnav.study_config import StudyConfig

    # the root config's sections of the commands each file is for (the others: the episode commands')
    sections = {"segmenter.yaml": SEGMENTER_SECTIONS, "calibrate_map.yaml": CALIBRATION_SECTIONS,
                "map_sequence.yaml": MAP_SECTIONS}
    # the study file is a plan of runs over root configs (each of its rows' configs is loaded by
    # tests/eval/objectnav/test_study.py::test_shipped_study_config_loads)
    # habitat-lab configs (habitat_*.yaml) are hydra configs of habitat-lab's schema: composed
    # by habitat-lab in tests/envs/test_habitat.py
    files = sorted(p for p in CONFIG_DIR.glob("*.yaml") if not p.name.startswith("habitat_"))
    assert files
    for path in files:
        if path.name == "study.yaml":
            load_config(path, cls=StudyConfig)
        elif path.name in sections:
            assert load_config(path, sections=sections[path.name]).sections == sections[path.name]
        else:
            load_config(path)


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
    with pytest.raises(ConfigError, match=r"resolution must be between 8x8 and 4096x4096"):
        load_config(None, ["env.resolution=4x4"])
    with pytest.raises(ConfigError, match=r"expected true or false"):
        load_config(None, ["env.enable_look=maybe"])


@pytest.mark.parametrize("overrides, cls, message", [
    (["run.backend=slurm"], Config, "run: unknown backend 'slurm' for run.backend; valid choices: local, ray"),
    (["mapping.fusion=bayes"], Config, "mapping: unknown fusion strategy 'bayes' for mapping.fusion; valid choices: "
                                       "rbu, averaging, histogram, geometric_mean, glfs"),
    (["mapping.weighting=gauss"], Config, "mapping: unknown sample weighting 'gauss' for mapping.weighting; valid "
                                          "choices: auto, none, lut, distance, incidence, sweet_spot"),
    (["sequences.layout=sevenscenes"], "calibrate", "sequences: unknown sequence layout 'sevenscenes'; valid choices: "
                                                    + ", ".join(LAYOUTS)),   # scannet, 7scenes, ...
    (["study.strategies=[rbu,bayes]"], "calibrate", "study: unknown fusion strategy 'bayes' in study.strategies; "
                                                    "valid choices: rbu, averaging, histogram, geometric_mean, glfs"),
])
def test_parts_chosen_by_name_are_checked_against_their_registry(overrides, cls, message):
    """A backend, fusion strategy, weighting or sequence layout is a name of its registry
    (``eval.backends.BACKENDS``, ``mapping.registry``): an unknown one is one line with the
    valid choices."""
    with pytest.raises(ConfigError) as exc:
        if cls == "calibrate":
            load_config(None, overrides, sections=CALIBRATION_SECTIONS)
        else:
            load_config(None, overrides)
    assert str(exc.value) == message


def test_validating_part_names_imports_neither_torch_nor_open3d():
    """The registries reference their parts lazily and every section's dataclass lives apart
    from the code that needs torch (the GLFS training section: ``mapping.calibration.glfs_config``)
    or Open3D (the scan section: ``envs.trajectories`` renders lazily): a config naming a fusion
    strategy, a weighting and a backend loads without either, and so does the calibration
    study's (the CLI's start-up stays fast). OpenCV (~25 ms) loads with the ``sequence``
    section's package, ``mapping.sequences``, whose readers decode frames with it."""
    import subprocess
    import sys

    code = ("import sys; from calnav.eval.config import load_config, CALIBRATION_SECTIONS; import calnav.eval.cli; "
            "load_config(None, ['mapping.fusion=glfs', 'mapping.weighting=lut', 'run.backend=ray']); "
            "load_config('configs/calibrate_map.yaml', sections=CALIBRATION_SECTIONS); "
            "print(sorted(m for m in ('torch', 'open3d') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_override_syntax_errors():
    with pytest.raises(ConfigError, match="key.subkey=value"):
        parse_override("env.split")
    with pytest.raises(ConfigError, match="not a section"):
        load_config(None, ["run.seed=1", "run.seed.x=2"])


def test_missing_file_is_clear(tmp_path):
    with pytest.raises(ConfigError, match=r"config file not found: .*missing.yaml; the shipped configs "
                                          r"\(found by name too\): .*demo.yaml, .*objectnav.yaml"):
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


# ------------------------------------------------------------ bad input before any work
def test_yaml_syntax_errors_are_one_line_config_errors(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("env:\n  split: [val\n")
    with pytest.raises(ConfigError, match=r"YAML syntax error in .*bad.yaml.*line \d+"):
        load_config(bad)
    with pytest.raises(ConfigError, match=r"YAML syntax error in override 'env.split=\[val'"):
        load_config(None, ["env.split=[val"])


def test_config_path_that_is_a_directory_is_refused(tmp_path):
    with pytest.raises(ConfigError, match=r"is a directory.*YAML file"):
        load_config(tmp_path)


def test_duplicate_yaml_keys_are_refused(tmp_path):
    path = tmp_path / "dup.yaml"
    path.write_text("env:\n  split: test\nrun:\n  seed: 1\nenv:\n  hfov_deg: 60\n")
    with pytest.raises(ConfigError, match=r"duplicate key 'env'.*line 5"):
        load_config(path)
    path.write_text("run:\n  seed: 1\n  seed: 2\n")
    with pytest.raises(ConfigError, match=r"duplicate key 'seed'.*line 3"):
        load_config(path)


def test_negative_workers_are_refused():
    with pytest.raises(ConfigError, match=r"run.workers must be >= 0"):
        load_config(None, ["run.workers=-1"])


def test_wxh_is_parsed_from_the_raw_text_and_0x0_is_a_bad_resolution(tmp_path):
    # YAML 1.1 reads 0x0 / 0x10 as hexadecimal integers: WxH must never go through that
    with pytest.raises(ConfigError, match=r"env.resolution must be between 8x8 and 4096x4096 pixels, got 0x0"):
        load_config(None, ["env.resolution=0x0"])
    with pytest.raises(ConfigError, match=r"got 0x16"):
        load_config(None, ["env.resolution=0x16"])
    path = tmp_path / "res.yaml"
    path.write_text("env:\n  resolution: 0x0\n")
    with pytest.raises(ConfigError, match=r"got 0x0"):
        load_config(path)


def test_segmenter_names_are_checked_at_load_time():
    with pytest.raises(ConfigError, match=r"unknown segmenter 'learnd_rgb'; valid: "
                                          r"gt, noisy, learned_rgb, learned_rgbd, hf, onnx, or a factory"):
        load_config(None, ["agent.segmenter=learnd_rgb"])
    with pytest.raises(ConfigError, match=r"unknown segmenter 'learnd_rgb'; valid: gt"):
        load_config(None, ["study.segmenters=[learnd_rgb]"], sections=CALIBRATION_SECTIONS)
    # an import path is accepted at load time (imported by the preflight, not here)
    assert load_config(None, ["agent.segmenter=mypkg.seg:make"]).agent.segmenter == "mypkg.seg:make"


def test_env_fields_of_view_are_ones_the_map_accepts():
    """A camera the voxel map would refuse mid-run (field of view outside (1, 179) deg) is a
    config error; the bounds are the map's."""
    from calnav.envs.config import FOV_BOUNDS_DEG
    from calnav.mapping.frame_geometry import MAX_FOV_DEG, MIN_FOV_DEG

    assert FOV_BOUNDS_DEG == (MIN_FOV_DEG, MAX_FOV_DEG)
    with pytest.raises(ConfigError, match=r"env.hfov_deg must be in \(1, 179\) degrees, got 179.5"):
        load_config(None, ["env.hfov_deg=179.5"])
    with pytest.raises(ConfigError, match=r"vertical field of view of 0.0\d+ deg.*outside \(1, 179\)"):
        load_config(None, ["env.hfov_deg=2", "env.resolution=1000x8"])
    load_config(None, ["env.hfov_deg=150"])


@pytest.mark.parametrize("override, message", [
    # "wrong results with exit 0": unrefused, each would run to a table of wrong numbers
    ("env.success_distance_m=nan", "env.success_distance_m.*expected a finite number"),
    ("agent.frontier_size_weight_m=nan", "agent.frontier_size_weight_m.*expected a finite number"),
    ("mapping.min_tsdf_weight=nan", "mapping.min_tsdf_weight.*expected a finite number"),
    ("env.turn_angle_deg=nan", "env.turn_angle_deg.*expected a finite number"),
    ("env.hfov_deg=inf", "env.hfov_deg.*expected a finite number"),
    ("env.max_episode_steps=0", r"env.max_episode_steps must be >= 1"),
    ("env.max_episode_steps=-3", r"env.max_episode_steps must be >= 1"),
    ("env.forward_step_m=-0.25", r"env.forward_step_m must be in \[0.01, 2\] metres, got -0.25"),
    ("env.camera_height_m=-1", r"env.camera_height_m must be in \[0.05, 3\] metres, got -1"),
    ("agent.goal_min_area_cells=-5", r"agent.goal_min_area_cells must be >= 1"),
    ("agent.frontier_size_weight_m=-1", r"agent.frontier_size_weight_m must be in \[0, 200\] metres"),
    ("env.resolution=40000x30000", r"env.resolution must be between 8x8 and 4096x4096 pixels"),
    ("mapping.initial_alloc_mb=1e12", r"mapping.initial_alloc_mb must be in \(0, 65536\] MiB"),
])
def test_non_finite_and_out_of_range_numbers_are_refused(override, message):
    with pytest.raises(ConfigError, match=message) as err:
        load_config(None, [override])
    assert "\n" not in str(err.value)


def test_glfs_eta_nan_and_a_zero_grid_are_refused():
    with pytest.raises(ConfigError, match="glfs.eta.*expected a finite number"):
        load_config(None, ["glfs.eta=nan"], sections=CALIBRATION_SECTIONS)
    # grid_points=0 is refused up front (not after 60 s of scans and 429 MB written)
    with pytest.raises(ConfigError, match=r"study.grid_points must be >= 2 \(got 0\)"):
        load_config(None, ["study.grid_points=0"], sections=CALIBRATION_SECTIONS)


def test_binary_or_unreadable_config_names_the_file(tmp_path):
    """A binary --config names the file (not a bare codec error)."""
    binary = tmp_path / "weights.yaml"
    binary.write_bytes(b"\x89PNG\x00\xff\xfe")
    with pytest.raises(ConfigError, match=rf"config {binary} is not a UTF-8 YAML text file \(byte 0"):
        load_config(binary)
    locked = tmp_path / "locked.yaml"
    locked.write_text("run:\n  seed: 1\n")
    locked.chmod(0)
    try:
        if not os.access(locked, os.R_OK):   # root reads anything
            with pytest.raises(ConfigError, match=rf"cannot read config {locked}"):
                load_config(locked)
    finally:
        locked.chmod(0o644)


def test_pydantic_validation_keeps_calnavs_messages():
    """The loader validates with pydantic (docs/configuration.md says why); the messages stay one
    line naming the key and what it takes, and pydantic's lax readings that would be wrong
    numbers are refused."""
    with pytest.raises(ConfigError, match=r"bad value for run.seed: True; expected an integer"):
        load_config(None, ["run.seed=true"])               # pydantic alone would read seed 1
    with pytest.raises(ConfigError, match=r"bad value for env.hfov_deg: False; expected a number"):
        load_config(None, ["env.hfov_deg=false"])
    with pytest.raises(ConfigError, match=r"bad value for mapping.glfs_params: None; expected a string"):
        load_config(None, ["mapping.glfs_params=null"])    # used to become the path "None"
    with pytest.raises(ConfigError, match=r"bad value for run.seed: 3.5; expected an integer"):
        load_config(None, ["run.seed=3.5"])
    assert load_config(None, ["run.seed=3.0"]).run.seed == 3   # an exact integer
    with pytest.raises(ConfigError, match=r"unknown config key 'study.glfs_variants\[0\].nme'; valid keys under "
                                          r"'study.glfs_variants\[0\]': name, overrides"):
        load_config(None, ["study.glfs_variants=[{nme: a}]"], sections=CALIBRATION_SECTIONS)
    with pytest.raises(ConfigError, match=r"^bad value for study.glfs_variants.a.overrides.eta: 'nan'; expected a finite"):
        load_config(None, ["study.glfs_variants=[{name: a, overrides: {eta: nan}}]"], sections=CALIBRATION_SECTIONS)
    with pytest.raises(ConfigError, match=r"bad value for env.resolution: \[1, 2, 3\]; expected 2 items"):
        load_config(None, ["env.resolution=[1,2,3]"])
    assert load_config(None, ["run.output_dir=64x48"]).run.output_dir == "64x48"   # WxH only for sizes
    # review findings: bools inside number lists, too few tuple items, mapping keys in the key path
    with pytest.raises(ConfigError, match=r"bad value for study.authors_miou_exclude: \[True, 2\]; expected a list of integers"):
        load_config(None, ["study.authors_miou_exclude=[true, 2]"], sections=CALIBRATION_SECTIONS)
    with pytest.raises(ConfigError, match=r"bad value for env.resolution: \[True, 120\]; expected a list of integers"):
        load_config(None, ["env.resolution=[true,120]"])
    with pytest.raises(ConfigError, match=r"bad value for env.resolution: \[160\]; expected 2 items"):
        load_config(None, ["env.resolution=[160]"])
    with pytest.raises(ConfigError, match=r"bad value for segmenter.confusions.a\[0\]: None; expected a string"):
        load_config(None, ["segmenter.confusions={a: [null]}"])
