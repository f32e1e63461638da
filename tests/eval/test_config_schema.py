"""The one root config (``eval.config.Config``): each command's sections (a file or override
setting another is one line naming the command's sections), the shorthand table (every
argument that sets a config key, checked against an override of the same key), and the
moved-key migration (an old key in a user's file or override is read at its new place, with a
note)."""
from __future__ import annotations

import dataclasses

import pytest
import yaml

from calnav.eval.cli import COMMANDS, main, parse_args
from calnav.eval.config import (EPISODE_SECTIONS, MOVED_KEYS, PREDICTOR_SECTIONS, SECTIONS, Config, ConfigError,
                                dump_yaml, load_config, migrate_tree)
from calnav.eval.sections import QUICK_PRESET
from tests.conftest import results_dir_like

OUT = "OUT"   # replaced by a path under tmp_path


def _argv(command: str, tmp_path) -> list[str]:
    """A minimal valid command line of ``command`` whose outputs lie under tmp_path/out."""
    out = tmp_path / "out"
    return [str(a).replace(OUT, str(out)) for a in {
        "check-scene": ["check-scene", "house_val_0000", "--output", OUT],
        "train-segmenter": ["train-segmenter", "--segmenter", "learned_rgb", "--output", f"{OUT}/w.pt"],
        "eval-segmenter": ["eval-segmenter", "--segmenter", "gt", "--output", f"{OUT}/m.json"],
        "train-predictor": ["train-predictor", "--data", tmp_path, "--output", f"{OUT}/p.pt"],
        "fit-glfs": ["fit-glfs", "--segmenter", "gt", "--output", f"{OUT}/g.json", "--work-dir", OUT],
        "map": ["map", tmp_path, "--layout", "scannet", "--segmenter", "gt", "--output", OUT],
        "replay": ["replay", tmp_path / "x.bag", "--goal", "chair", "--output", OUT],
        "reproduce": ["reproduce", results_dir_like(tmp_path / "run"), "--episodes", "0:1"],
    }.get(command, [command, "--output", OUT])]


def _commands():
    """(name, its declaration) of every registered command."""
    return [(name, COMMANDS.get(name)) for name in COMMANDS]


# the commands whose loader reads a config (study's reads a plan file: tests/eval/objectnav/test_study.py)
LOADED = sorted(name for name, c in _commands() if c.configs is not None and name != "study")


def test_every_command_declares_sections_of_the_root_config():
    """A command with a config loader declares a non-empty subset of the root's sections; one
    without declares none; every section is some command's."""
    for name, c in _commands():
        assert set(c.sections) <= set(SECTIONS), name
        assert bool(c.sections) == (c.configs is not None), name
    assert {s for c in (c for _, c in _commands()) for s in c.sections} == set(SECTIONS)


@pytest.mark.parametrize("command", [c for c in LOADED if c != "habitat-benchmark"])   # needs habitat-lab's venv
def test_a_command_loads_exactly_its_sections(command, tmp_path):
    """The loaded config holds the command's sections (the others are None) and its dump --
    the results directory's config.yaml -- exactly them."""
    (tmp_path / "out").mkdir()
    cfg = COMMANDS.get(command).load_configs(parse_args(_argv(command, tmp_path)))[0]
    assert isinstance(cfg, Config) and cfg.sections == COMMANDS.get(command).sections
    assert all(getattr(cfg, s) is None for s in SECTIONS if s not in cfg.sections)
    assert list(yaml.safe_load(dump_yaml(cfg))) == list(COMMANDS.get(command).sections)


@pytest.mark.parametrize("command", LOADED)
def test_a_section_the_command_does_not_use_is_one_line(command, tmp_path, capsys):
    """An override or a config file setting a section of the root config the command does not
    use is refused in one line naming the command's sections, before anything is written."""
    sections = COMMANDS.get(command).sections
    unused = next(s for s in SECTIONS if s not in sections)
    key = f"{unused}.{dataclasses.fields(_section(unused))[0].name}"
    expected = f"which calnav {command} does not use; its sections: {', '.join(sections)}"
    assert main([*_argv(command, tmp_path), f"{key}=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"the override {key}=1 sets the '{unused}' section, {expected}" in err[0], err
    if "--config" in _parser_options(command):
        path = tmp_path / "c.yaml"
        path.write_text(f"{unused}: {{}}\n")
        assert main([*_argv(command, tmp_path), "--config", str(path)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"{path} sets the '{unused}' section, {expected}" in err[0], err
    assert not (tmp_path / "out").exists()


def _section(name: str) -> type:
    """The dataclass of the root config's section ``name``."""
    import typing

    from calnav.eval.validation import section_type

    return section_type(typing.get_type_hints(Config)[name])


def _parser_options(command: str) -> set[str]:
    """The options ``calnav COMMAND`` takes."""
    from calnav.eval.parser import build_parser

    parser = build_parser(command)
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    return {o for a in sub.choices[command]._actions for o in a.option_strings}


def test_an_unknown_top_level_key_lists_the_commands_sections():
    with pytest.raises(ConfigError, match=r"^unknown config key 'nope'; valid keys at the top level: "
                                          r"predictor_train$"):
        load_config(None, ["nope.x=1"], sections=PREDICTOR_SECTIONS)
    with pytest.raises(ConfigError, match=r"^bad value for segmenter: null; expected a mapping of SegmenterConfig "
                                          r"keys$"):
        load_config(None, ["segmenter=null"])


# ------------------------------------------------------------------------------ shorthands
def _conflicts() -> list[tuple[str, str, str, list[str], str]]:
    """(command, option, key, argv, override) for every key every shorthand of the command
    table may set: the shorthand given with an override of its key."""
    cases = [
        ("objectnav", "--agent", "run.agent", ["--agent", "oracle"], "run.agent=peanut"),
        ("habitat-benchmark", "--agent", "run.agent", ["--agent", "oracle"], "run.agent=peanut"),
        ("view-episode", "--agent", "run.agent", ["--agent", "peanut"], "run.agent=oracle"),
        ("start-pose", "--workers", "run.workers", ["--workers", "2"], "run.workers=1"),
        ("scan-houses", "", "env.dataset.style", [], "env.dataset.style=clean"),
        ("check-scene", "target", "env.dataset.scene_dir", [], "env.dataset.scene_dir=elsewhere"),
        ("collect-maps", "--split", "env.split", ["--split", "val"], "env.split=train"),
        ("export-habitat", "--split", "env.split", ["--split", "val", "--output", "out"], "env.split=train"),
        ("collect-maps", "--steps", "env.max_episode_steps", ["--steps", "40"], "env.max_episode_steps=10"),
        ("train-predictor", "--epochs", "predictor_train.epochs", ["--epochs", "2"], "predictor_train.epochs=3"),
        ("train-predictor", "--pos-weight", "predictor_train.pos_weight", ["--pos-weight", "2"],
         "predictor_train.pos_weight=3"),
        ("train-predictor", "--seed", "predictor_train.seed", ["--seed", "1"], "predictor_train.seed=2"),
        ("train-predictor", "--val-fraction", "predictor_train.val_fraction", ["--val-fraction", "0.2"],
         "predictor_train.val_fraction=0.3"),
        ("calibrate-map", "--sequences", "sequences.list", ["--sequences", "list.txt"], "sequences.list=other.txt"),
        ("fit-glfs", "--segmenter", "study.segmenters", [], "study.segmenters=[gt]"),   # _argv gives --segmenter gt
        ("fit-glfs", "", "study.strategies", [], "study.strategies=[glfs]"),
        ("export-sequence", "--resolution", "env.resolution", ["--resolution", "64x48"], "env.resolution=32x24"),
        ("export-sequence", "--frames", "scan.frames", ["--frames", "3"], "scan.frames=2"),
        ("demo", "--output", "run.output_dir", [], "run.output_dir=elsewhere"),   # _argv gives --output
        ("replay", "--segmenter", "agent.segmenter", ["--segmenter", "gt"], "agent.segmenter=noisy"),
        ("replay", "", "env.normalize_depth", [], "env.normalize_depth=true"),
    ]
    cases += [("calibrate-map", "--quick", key, ["--quick"], f"{key}={value + 1}") for key, value in QUICK_PRESET]
    return cases


CONFLICTS = _conflicts()


def test_every_shorthand_of_the_command_table_has_a_conflict_case():
    declared = {(name, sh.option, key) for name, c in _commands()
                for sh in c.shorthands() for key in sh.keys()}
    assert declared == {case[:3] for case in CONFLICTS}


@pytest.mark.parametrize("command, option, key, extra, override", CONFLICTS,
                         ids=[f"{c}{o or ' (fixed)'}->{k}" for c, o, k, _, _ in CONFLICTS])
def test_a_shorthand_and_an_override_of_its_key_are_one_line(command, option, key, extra, override, tmp_path,
                                                               capsys):
    """Every argument that sets a config key, given next to an override of that key: refused in
    one line naming both (or, for a value the command always sets, the override to remove),
    before anything is written -- the shorthand never silently wins, nor the override."""
    argv = _argv(command, tmp_path)
    if option == "target":
        argv[1] = str(tmp_path)   # a directory: its scenes, as env.dataset.scene_dir
    assert main([*argv, *extra, override]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and key in err[0] and override in err[0], err
    if option:
        assert "both set" in err[0] and "give one of them" in err[0], err
    else:
        assert f"calnav {command} sets {key}=" in err[0] and "itself; remove the override" in err[0], err
    assert not (tmp_path / "out").exists()


def _loaded(argv: list[str]) -> Config:
    args = parse_args(argv)
    return COMMANDS.get(args.command).load_configs(args)[0]


def test_shorthand_defaults_lie_under_the_overrides(tmp_path):
    """A shorthand not given sets its command's default, which an override changes: collect-maps
    explores 250 steps of the train split, view-episode draws the oracle's path, export-sequence
    renders 640x480; given, the shorthand's value (converted) is the key's."""
    out = str(tmp_path / "o")
    cfg = _loaded(["collect-maps", "--output", out])
    assert (cfg.env.split, cfg.env.max_episode_steps) == ("train", 251)
    cfg = _loaded(["collect-maps", "--output", out, "env.split=val", "env.max_episode_steps=11"])
    assert (cfg.env.split, cfg.env.max_episode_steps) == ("val", 11)
    assert _loaded(["collect-maps", "--output", out, "--steps", "40", "--split", "val"]).env.max_episode_steps == 41
    assert _loaded(["view-episode"]).run.agent == "oracle"
    assert _loaded(["view-episode", "run.agent=peanut"]).run.agent == "peanut"
    cfg = _loaded(["export-sequence", "--output", out])
    assert cfg.env.resolution == (640, 480) and cfg.scan.frames == 500   # configs/calibrate_map.yaml's scan
    assert _loaded(["export-sequence", "--output", out, "--frames", "0"]).scan.frames == 500   # 0: the config's
    assert _loaded(["demo"]).run.output_dir == "runs/demo"
    assert _loaded(["check-scene", "house_val_0000"]).env.dataset.scene_dir == ""   # a calnav house: no folder
    assert _loaded(["check-scene", str(tmp_path)]).env.dataset.scene_dir == str(tmp_path)
    fit = _loaded(["fit-glfs", "--segmenter", "gt", "--output", out])
    assert (fit.study.segmenters, fit.study.strategies) == (["gt"], ["glfs"])


def test_train_predictor_options_are_its_sections_keys(tmp_path):
    """``--epochs / --pos-weight / --seed / --val-fraction`` set ``predictor_train``; their
    defaults are the section's (the trainer's former option defaults)."""
    base = ["train-predictor", "--data", str(tmp_path)]
    cfg = _loaded(base).predictor_train
    assert (cfg.epochs, cfg.pos_weight, cfg.seed, cfg.val_fraction, cfg.batch_size, cfg.lr) == (12, 20.0, 0, 0.15,
                                                                                              16, 1e-3)
    cfg = _loaded([*base, "--epochs", "3", "--pos-weight", "5", "--seed", "7", "--val-fraction", "0.25",
                   "predictor_train.lr=5e-4"]).predictor_train
    assert (cfg.epochs, cfg.pos_weight, cfg.seed, cfg.val_fraction, cfg.lr) == (3, 5.0, 7, 0.25, 5e-4)


# ------------------------------------------------------------------------------ moved keys
def test_moved_keys_are_not_keys_of_the_schema_and_their_new_places_are():
    hints = {s: _section(s) for s in SECTIONS}
    for old, new in MOVED_KEYS.items():
        section, _, rest = old.partition(".")
        assert rest not in {f.name for f in dataclasses.fields(hints[section])}, old
        assert new.split(".")[0] in SECTIONS, new


def test_an_old_key_in_a_users_file_or_override_is_read_at_its_new_place(tmp_path, capsys):
    """``agent.segmenter_config`` (the segmenter's settings inside ``agent``, before they became
    the top-level ``segmenter`` section) in a user's file or override: the same config as the new
    form, with one note on stderr naming the new key; both places at once is a one-line error."""
    old, new = tmp_path / "old.yaml", tmp_path / "new.yaml"
    old.write_text("agent:\n  segmenter: learned_rgb\n  segmenter_config:\n    threads: 2\n    trace: false\n")
    new.write_text("agent:\n  segmenter: learned_rgb\nsegmenter:\n  threads: 2\n  trace: false\n")
    capsys.readouterr()
    assert load_config(old) == load_config(new)
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"calnav: note: {old}: agent.segmenter_config has moved to segmenter and is read there; "
                   "write segmenter"]
    assert "segmenter_config" not in dump_yaml(load_config(old))
    assert load_config(None, ["agent.segmenter_config.threads=3"]).segmenter.threads == 3
    assert "override agent.segmenter_config.threads=3: agent.segmenter_config has moved to segmenter" in \
        capsys.readouterr().err
    both = tmp_path / "both.yaml"
    both.write_text("agent:\n  segmenter_config:\n    threads: 2\nsegmenter:\n  threads: 1\n")
    with pytest.raises(ConfigError, match=rf"^{both}: agent.segmenter_config and segmenter are one setting "
                                          r"\(agent.segmenter_config moved to segmenter\); write only segmenter$"):
        load_config(both)


def test_migrating_a_stored_config_is_silent_and_leaves_it_unchanged(capsys):
    """A stored config.yaml (results directories, ``calnav compare``) is migrated without a note
    and without changing the dict it was read into."""
    stored = {"agent": {"segmenter": "gt", "segmenter_config": {"threads": 2}}, "run": {"seed": 1}}
    assert migrate_tree(stored) == {"agent": {"segmenter": "gt"}, "run": {"seed": 1}, "segmenter": {"threads": 2}}
    assert stored["agent"]["segmenter_config"] == {"threads": 2}
    assert capsys.readouterr().err == ""
    assert set(EPISODE_SECTIONS) >= set(migrate_tree(stored))
