"""Every file a config names is opened and validated before a run writes anything or starts a
worker (``eval.preflight``), for every command of the registry ``eval.parser.COMMANDS``, on exactly
the configs the command then runs."""
from __future__ import annotations

import json
import math

import pytest

from calnav.agent.segmenters.base import WEIGHTS_DIR
from calnav.eval.cli import main
from calnav.eval.config import load_config
from calnav.eval.preflight import check_run_resources
from tests.conftest import results_dir_like

SHIPPED_GLFS = WEIGHTS_DIR / "glfs_learned_rgb.json"
SMALL = ["env.resolution=32x24", "env.dataset.val_scenes=2", "env.dataset.episodes_per_scene=3"]


def _glfs_variant(tmp_path, name: str, edit) -> str:
    d = json.loads(SHIPPED_GLFS.read_text())
    edit(d)
    path = tmp_path / name
    path.write_text(json.dumps(d))   # json writes NaN as the bare token NaN, as Python reads it back
    return str(path)


def _drop_last_class(d: dict) -> None:
    d["tau"], d["M"], d["class_names"] = d["tau"][:-1], d["M"][:-1], d["class_names"][:-1]


def _nan_tau(d: dict) -> None:
    d["tau"][0] = math.nan


def bad_files(tmp_path) -> dict[str, tuple[list[str], str]]:
    """name -> (overrides naming a damaged file, regex the error must match)."""
    truncated_weights = tmp_path / "truncated.pt"
    truncated_weights.write_bytes((WEIGHTS_DIR / "learned_rgb.pt").read_bytes()[:5000])
    truncated_glfs = tmp_path / "truncated.json"
    truncated_glfs.write_text(SHIPPED_GLFS.read_text()[:300])
    learned = ["agent.segmenter=learned_rgb"]
    return {
        "missing weights": (learned + [f"segmenter.weights={tmp_path / 'none.pt'}"],
                            r"segmenter weights not found: .*none.pt.*calnav train-segmenter"),
        "truncated weights": (learned + [f"segmenter.weights={truncated_weights}"],
                              r"cannot read segmenter weights .*truncated.pt"),
        "missing glfs": (learned + [f"mapping.glfs_params={tmp_path / 'none.json'}"],
                         r"GLFS params file not found: .*none.json"),
        "truncated glfs": (learned + [f"mapping.glfs_params={truncated_glfs}"], r"corrupt GLFS params file .*truncated"),
        "nan glfs": (learned + [f"mapping.glfs_params={_glfs_variant(tmp_path, 'nan.json', _nan_tau)}"],
                     r"nan.json.*tau must be finite"),
        "17-class glfs": (learned + [f"mapping.glfs_params={_glfs_variant(tmp_path, 'k17.json', _drop_last_class)}"],
                          r"k17.json.*17 classes.*18"),
        "missing scene_dir": ([f"env.dataset.scene_dir={tmp_path / 'nowhere'}"], r"scene_dir .*nowhere.* is not a directory"),
        "empty scene_dir": ([f"env.dataset.scene_dir={tmp_path}"], r"no scenes found in .*"),
    }


def test_shipped_resources_pass():
    check_run_resources(load_config(None, ["agent.segmenter=learned_rgb",
                                           "mapping.glfs_params=agent/weights/glfs_learned_rgb.json"]))
    check_run_resources(load_config("configs/objectnav.yaml"))


@pytest.mark.parametrize("case", ["missing weights", "truncated weights", "missing glfs", "truncated glfs",
                                  "nan glfs", "17-class glfs", "missing scene_dir", "empty scene_dir"])
def test_damaged_files_are_named_before_the_run(tmp_path, case):
    overrides, message = bad_files(tmp_path)[case]
    cfg = load_config(None, overrides)      # the loader cannot know: the files are opened by the preflight
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        check_run_resources(cfg)


@pytest.mark.parametrize("workers", ["1", "2"])
def test_objectnav_refuses_bad_weights_before_writing(tmp_path, capsys, workers):
    out = tmp_path / "run"
    overrides, message = bad_files(tmp_path)["truncated weights"]
    code = main(["objectnav", "--output", str(out), "--episodes", "2", *SMALL, f"run.workers={workers}", *overrides])
    err = capsys.readouterr().err
    assert code == 2 and "cannot read segmenter weights" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists()                  # nothing written: the corrected rerun is not "another config"


def test_objectnav_multirun_checks_every_combination(tmp_path, capsys):
    out = tmp_path / "multi"
    glfs = bad_files(tmp_path)["nan glfs"][0][1]
    code = main(["objectnav", "-m", "--output", str(out), *SMALL, "agent.segmenter=gt,learned_rgb", glfs])
    assert code == 2 and "tau must be finite" in capsys.readouterr().err
    assert not out.exists()


def test_tune_refuses_bad_glfs_before_writing(tmp_path, capsys):
    out = tmp_path / "tune"
    overrides, _ = bad_files(tmp_path)["17-class glfs"]
    assert main(["tune", "--output", str(out), "--episodes", "0:2", *SMALL, *overrides]) == 2
    assert "17 classes" in capsys.readouterr().err
    assert not out.exists()


def test_calibrate_map_and_fit_glfs_refuse_bad_weights_before_writing(tmp_path, capsys):
    # the study's segmenters load their shipped weights; what a config can name wrongly is the
    # scene folder, the GLFS file and the segmenter itself
    missing = tmp_path / "none.json"
    study = tmp_path / "study"
    assert main(["calibrate-map", "--output", str(study), "study.segmenters=[learned_rgb]",
                 f"env.dataset.scene_dir={tmp_path / 'nowhere'}"]) == 2
    assert "is not a directory" in capsys.readouterr().err
    assert not study.exists()
    work = tmp_path / "work"
    assert main(["fit-glfs", "--segmenter", "learned_rgb", "--output", str(tmp_path / "g.json"),
                 "--work-dir", str(work), f"mapping.glfs_params={missing}"]) == 2
    assert "GLFS params file not found" in capsys.readouterr().err
    assert not work.exists()
    assert main(["fit-glfs", "--segmenter", "learnd_rgb", "--output", str(tmp_path / "g.json"),
                 "--work-dir", str(work)]) == 2
    assert "unknown segmenter 'learnd_rgb'; valid: gt, noisy, learned_rgb, learned_rgbd" in capsys.readouterr().err
    assert not work.exists()


def _argv(command: str, tmp_path) -> list[str]:
    """A minimal valid command line for each registered command (outputs under tmp_path)."""
    out = str(tmp_path / "out")
    return {
        "map": ["map", str(tmp_path), "--layout", "scannet", "--segmenter", "gt", "--output", out],
        "replay": ["replay", str(tmp_path / "x.bag"), "--goal", "chair", "--output", out],
        "fit-glfs": ["fit-glfs", "--segmenter", "gt", "--output", str(tmp_path / "g.json")],
        "train-segmenter": ["train-segmenter", "--segmenter", "learned_rgb"],
        "eval-segmenter": ["eval-segmenter", "--segmenter", "gt"],
        "export-onnx": ["export-onnx", "--segmenter", "learned_rgb", "--output", str(tmp_path / "m.onnx")],
        "train-predictor": ["train-predictor", "--data", str(tmp_path), "--output", str(tmp_path / "p.pt")],
        "export-sequence": ["export-sequence", "--output", out],
        "compare": ["compare", out, "--output", out],
        "calibrate-map": ["calibrate-map", "--quick", "--sequences", str(tmp_path / "list.txt")],
        "view": ["view", str(tmp_path)],
        "check-scene": ["check-scene", "house_val_0000", "--output", out],
        "study": ["study", "configs/study.yaml", "--output", out],
        "report": ["report", str(tmp_path / "manifest.json")],
        "reproduce": ["reproduce", results_dir_like(tmp_path / "run"), "--episodes", "0:1"],
    }.get(command, [command, "--output", out])



def assert_runs_the_checked_configs(argv: list[str], monkeypatch) -> list:
    """Run ``calnav *argv`` with the command's main and the preflight's per-config check spied
    on; assert the main received exactly the config objects the preflight checked. Returns them."""
    import importlib

    import calnav.eval.preflight as preflight
    from calnav.eval.cli import COMMANDS

    entry = COMMANDS.get(argv[0])
    checked, received = [], []
    monkeypatch.setattr(preflight, "check_run_resources", lambda cfg, checks=(): checked.append(cfg))
    monkeypatch.setattr(importlib.import_module(entry.main.__module__), entry.main.__name__,
                        lambda args, configs: received.append(configs))
    assert main(argv) == 0
    assert len(received) == 1 and [id(c) for c in received[0]] == [id(c) for c in checked]
    assert bool(checked) == (entry.configs is not None), f"{argv[0]}: checked {checked}"
    return checked


@pytest.mark.parametrize("command", sorted(set(__import__("calnav.eval.cli", fromlist=["COMMANDS"]).COMMANDS)
                                           - {"habitat-benchmark"}))   # in tests/envs/test_habitat.py
def test_every_command_runs_the_configs_the_preflight_checked(tmp_path, monkeypatch, command):
    """The CLI loads a command's configs once, the preflight checks them and the command's main
    receives the very same objects (before, preflight reloaded configs by its own rules: it
    dropped ``calibrate-map --sequences`` and covered 4 of 15 commands)."""
    (tmp_path / "list.txt").write_text(f"test {tmp_path}\n")
    checked = assert_runs_the_checked_configs(_argv(command, tmp_path), monkeypatch)
    if command == "calibrate-map":   # the shorthand reaches the checked config
        assert checked[0].sequences.list == str(tmp_path / "list.txt")


@pytest.mark.parametrize("command", [
    ["view-episode", "--agent", "peanut"], ["start-pose"], ["map", "SEQ", "--layout", "scannet", "--segmenter", "gt"],
])
def test_commands_refuse_a_missing_glfs_file_before_writing(tmp_path, capsys, command):
    """Commands the preflight did not cover before: a config naming a missing file is one line
    and nothing is written."""
    out = tmp_path / "out"
    argv = [a.replace("SEQ", str(tmp_path)) for a in command]
    code = main([*argv, "--output", str(out), f"mapping.glfs_params={tmp_path / 'none.json'}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "GLFS params file not found" in err[0]
    assert not out.exists()


def test_preflight_checks_only_what_a_command_uses(tmp_path, capsys):
    """export-sequence segments nothing and scan-houses runs no agent: a study segmenter, a GLFS
    file or a scene folder without every split does not stop them (each command declares its
    checks in the registry); view-episode checks the agent it draws, not the config's."""
    scenes = tmp_path / "scenes"
    (scenes / "val").mkdir(parents=True)
    from calnav.envs.primitives import box_room_scene

    box_room_scene(name="myhouse").save(scenes / "val" / "myhouse.npz")
    out = tmp_path / "exp"
    assert main(["export-sequence", "--scene", "myhouse", "--frames", "3", "--resolution", "64x48",
                 "--output", str(out), f"env.dataset.scene_dir={scenes}",
                 f"mapping.glfs_params={tmp_path / 'none.json'}"]) == 0
    assert (out / "pose").is_dir()
    # the default --agent oracle neither segments nor needs a semantic sensor or a device
    view = tmp_path / "view"
    assert main(["view-episode", "--output", str(view), *SMALL, "agent.segmenter=gt",
                 "env.semantic_sensor=false"]) == 0
    assert main(["view-episode", "--agent", "peanut", "--output", str(view), *SMALL, "agent.segmenter=gt",
                 "env.semantic_sensor=false"]) == 2
    assert "reads the ground-truth semantic observation" in capsys.readouterr().err


def test_a_segmenter_that_reads_ground_truth_needs_a_semantic_sensor(tmp_path, capsys):
    """`agent.segmenter=gt` without the semantic sensor: every episode used to crash on its first
    step (habitat-benchmark's default habitat config: a KeyError traceback); now one line, before
    anything is written. The oracle and the learned segmenters need no semantic sensor."""
    out = tmp_path / "run"
    code = main(["objectnav", "--output", str(out), "--episodes", "1", *SMALL, "env.semantic_sensor=false",
                 "agent.segmenter=gt"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "reads the ground-truth semantic observation" in err[0]
    assert "configs/habitat_objectnav_semantic.yaml" in err[0] and not out.exists()
    check_run_resources(load_config(None, ["env.semantic_sensor=false", "agent.segmenter=learned_rgb"]))
    check_run_resources(load_config(None, ["env.semantic_sensor=false", "run.agent=oracle"]))
