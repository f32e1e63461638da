"""Every ``calnav`` command is declared once (a flags dataclass and a ``Command`` beside its main,
registered in ``eval.parser.COMMANDS``): the parser, ``--help``, the shorthands and docs/cli.md's
reference table all come from that declaration."""
from __future__ import annotations

import contextlib
import dataclasses
import io
import re
from pathlib import Path

import pytest

from calnav.common.registry import Registry
from calnav.eval.arguments import Command, spelling
from calnav.eval.cli import main, parse_args
from calnav.eval.parser import COMMANDS, render_page

REPO = Path(__file__).resolve().parents[2]
SEGMENTER_COMMANDS = ("train-segmenter", "eval-segmenter", "export-onnx", "map", "replay", "fit-glfs")


def _help(argv: list[str]) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 0
    return re.sub(r"\s+", " ", out.getvalue())


def test_the_commands_are_one_shared_registry_of_declarations():
    assert isinstance(COMMANDS, Registry) and len(COMMANDS) >= 25
    for name in COMMANDS:
        command = COMMANDS.get(name)
        assert isinstance(command, Command) and dataclasses.is_dataclass(command.args), name
        for f in command.fields():
            assert f.metadata["help"], f"{name} {spelling(f)} has no help"


def test_one_generic_add_parser_in_eval():
    calls = sum(p.read_text().count("add_parser(") for p in (REPO / "eval").rglob("*.py"))
    assert calls <= 2


def test_help_lists_every_command_and_every_flag_with_its_help():
    top = _help(["--help"])
    for name, text in COMMANDS.describe().items():
        assert name in top and " ".join(text.split()[:4]) in top
    for name in ("objectnav", "train-predictor", "map", "bench"):
        page = _help([name, "--help"])
        assert page.startswith(f"usage: calnav {name}")
        for f in COMMANDS.get(name).fields():
            assert spelling(f) in page and " ".join(f.metadata["help"].replace("%%", "%").split()[:3]) in page


def test_the_segmenter_is_spelled_segmenter_on_every_command():
    for name in COMMANDS:
        flags = [spelling(f) for f in COMMANDS.get(name).fields()]
        assert "--model" not in flags, name
        assert ("--segmenter" in flags) == (name in SEGMENTER_COMMANDS), name
    assert parse_args(["eval-segmenter", "--segmenter", "gt"]).segmenter == "gt"


@pytest.mark.parametrize("argv, value", [
    (["eval-segmenter", "--model", "gt", "--frames", "3"], " gt"),
    (["train-segmenter", "--model=learned_rgb"], " learned_rgb"),
    (["export-onnx", "--output", "m.onnx", "--model"], ""),
])
def test_the_renamed_model_flag_is_one_line_naming_segmenter(argv, value, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert exit_.value.code == 2
    assert err == [f"calnav {argv[0]}: error: --model is now --segmenter: write --segmenter{value}"]


@pytest.mark.parametrize("argv, message", [
    (["objectnav", "--video", "-1"], "--video must be in [0, 1000000] episodes, got -1"),
    (["bench", "--scene-seed", "-3"], "--scene-seed must be in [0, 4294967295], got -3"),
    (["export-sequence", "--max-edge", "0", "--output", "o"], "--max-edge must be in (0, 10] metres, got 0.0"),
    (["check-scene", "house_val_0000", "--episodes", "0"], "--episodes must be in [1, 100000] episodes, got 0"),
])
def test_a_flag_outside_its_range_is_one_line(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(REPO)
    assert main(argv) == 2
    assert capsys.readouterr().err.strip().splitlines() == [f"calnav {argv[0]}: error: {message}"]


def test_shorthands_come_from_the_flags_declarations():
    keys = {sh.option: sh.key for sh in COMMANDS.get("train-predictor").shorthands()}
    assert keys == {f"--{k.replace('_', '-')}": f"predictor_train.{k}"
                    for k in ("val_fraction", "epochs", "pos_weight", "seed")}
    replay = COMMANDS.get("replay").shorthands()
    assert [(sh.option, sh.key, sh.default) for sh in replay[:1]] == [("--segmenter", "agent.segmenter", "learned_rgb")]
    assert replay[-1].preset == (("env.normalize_depth", "false"),)


def test_the_cli_page_table_is_the_registrys_rendering():
    page = (REPO / "docs" / "cli.md").read_text()
    assert render_page(page) == page, "re-render it: python -m calnav.eval.parser docs/cli.md"
    assert "| | `--segmenter SEGMENTER` |" in page and "--model" not in page
