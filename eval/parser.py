"""The ``calnav`` argument parser, built from the command registry ``COMMANDS``: each command is
declared once, beside its main, as an ``eval.arguments.Command`` (its flags' dataclass, its main,
what it reads of the config); the registry holds its name, a lazy reference to it and its help.
``calnav --help`` imports no command module (only the registry's names and helps load); a
command's own parser imports that command's module."""
from __future__ import annotations

import argparse

from calnav.common.registry import Registry
from calnav.eval.arguments import Command, add_arguments
from calnav.eval.config import moved_flag


DESCRIPTION = ("ObjectNav on a calibrated semantic 3D map: run episodes, switch the fusion strategy, segmenter "
               "or calibration with one config key, and compare navigation and map-calibration metrics.")
EPILOG = ("Start with `calnav demo`; `calnav COMMAND --help` gives a command's options. The commands that run "
          "an agent or build a map take --config FILE and KEY=VALUE overrides (docs/configuration.md).")
OVERRIDES_HELP = "dotted config overrides, e.g. env.resolution=160x120 mapping.fusion=glfs"

COMMANDS: Registry[Command] = Registry("command")
for _name, _ref, _help in (
    ("objectnav", "objectnav.run:COMMAND", "run ObjectNav episodes and report Success/SPL/SoftSPL/DTG"),
    ("start-pose", "objectnav.start_pose:COMMAND", "the peanut agent under frame changes and rotated houses "
                                                   "(is it equally good whatever the start pose?)"),
    ("habitat-benchmark", "habitat.run:COMMAND", "run an agent through habitat-lab's habitat.Benchmark on calnav "
                                                 "houses (needs habitat-lab: make habitat-setup)"),
    ("export-habitat", "habitat.export:COMMAND", "write a split's houses and episodes in HM3D v0.2's layout with "
                                                 "habitat-lab ObjectNav episode files (for habitat-sim; read back "
                                                 "with env.dataset.data_path)"),
    ("view-episode", "objectnav.view_episode:COMMAND", "top-down map PNG and a frame strip of one episode"),
    ("scan-houses", "scanning.run:COMMAND", "scan (and cache) the houses of splits for env.dataset.style=scanned; "
                                            "how scan-like they are (quality.csv / quality.md)"),
    ("check-scene", "scanning.check:COMMAND", "what the simulator makes of a scene: walkable floor, navigable area, "
                                              "islands, passages too narrow for the agent, episodes generated / "
                                              "rejected; a top-down PNG (and a Rerun recording with the viz extra)"),
    ("bench", "bench.run:COMMAND", "speed/memory figures as a flat JSON of name -> number"),
    ("train-segmenter", "segmenter.train:COMMAND", "train a learned segmenter on frames of the train split"),
    ("collect-maps", "prediction.collect:COMMAND", "training maps for the target predictor: the agent explores "
                                                   "train houses, partial maps + ground-truth goal cells every "
                                                   "--every steps"),
    ("train-predictor", "prediction.train:COMMAND", "train the target predictor on collect-maps output; held-out "
                                                    "AUC / AP"),
    ("export-onnx", "segmenter.export_onnx:COMMAND", "a learned segmenter as an ONNX model for the onnx adapter "
                                                     "(checked against torch before it is written)"),
    ("eval-segmenter", "segmenter.evaluate:COMMAND", "accuracy / mIoU / ECE / mECE of a segmenter on held-out frames"),
    ("calibrate-map", "calibration.study:CALIBRATE_MAP", "the map-calibration study: fusion strategies x "
                                                         "calibration methods, results.csv / results.md / plots"),
    ("map", "sequence.map_cmd:COMMAND", "fuse a recorded RGB-D sequence (ScanNet / 7-Scenes layout, ROS bag) into "
                                        "a semantic map and score it against a labelled mesh"),
    ("replay", "sequence.replay:COMMAND", "what the ObjectNav agent would do on a recording (ROS bag, ScanNet / "
                                          "7-Scenes layout), open loop: per-frame actions, detections, goals, "
                                          "STOPs; the map"),
    ("export-sequence", "sequence.export:COMMAND", "write calnav's own frames (a house's calibration scan) in "
                                                   "ScanNet layout, with a labelled mesh"),
    ("fit-glfs", "calibration.study:FIT_GLFS", "record calibration scans and train GLFS parameters for one "
                                               "segmenter"),
    ("tune", "objectnav.tune:COMMAND", "grid-search agent.goal_threshold x agent.goal_min_area_cells (peanut "
                                       "agent); tune.csv + best.yaml"),
    ("study", "objectnav.study:COMMAND", "the ObjectNav study of a study config: tune each row's goal threshold, "
                                         "evaluate on held-out episodes, write manifest.json (resumable)"),
    ("report", "objectnav.study_report:COMMAND", "a study's results page (results.md, threshold_curves.png) from "
                                                 "its manifest and records"),
    ("reproduce", "objectnav.reproduce:COMMAND", "rerun episodes of a results directory with its own config and "
                                                 "compare every record field (exit 1 if one differs): does the code "
                                                 "now give the same results?"),
    ("compare", "objectnav.compare:COMMAND", "one comparison table (+ paired differences) from finished objectnav "
                                             "runs"),
    ("view", "sequence.view:COMMAND", "open Rerun recordings (.rrd, a map.npz, or a results directory's) in the "
                                      "Rerun viewer, or print the command where there is no display (needs the "
                                      "[viz] extra)"),
    ("demo", "objectnav.demo:COMMAND", "set-up check + a real ObjectNav evaluation on procedural houses"),
):
    COMMANDS.add(_name, f"calnav.eval.{_ref}", _help)


def add_config_args(p: argparse.ArgumentParser, command: Command) -> None:
    """``--config FILE`` and the ``KEY=VALUE`` overrides, as ``command`` declares them."""
    if command.config is not None:
        p.add_argument("--config", default=command.config or None,
                       help=command.config_help or f"YAML config (default: {command.config})")
    if command.overrides is not None:
        p.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help=command.overrides or OVERRIDES_HELP)


def command_parser(p: argparse.ArgumentParser, command: Command) -> argparse.ArgumentParser:
    """``p`` with every argument of ``command``: its positionals, --config and the overrides, its options."""
    add_arguments(p, command, after_positionals=lambda: add_config_args(p, command))
    return p


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``calnav`` parser: every command with its help; ``command``'s with its arguments (the
    others' modules are not imported)."""
    parser = argparse.ArgumentParser(prog="calnav", description=DESCRIPTION, epilog=EPILOG)
    sub = parser.add_subparsers(dest="command", required=True)
    for name, help in COMMANDS.describe().items():
        p = sub.add_parser(name, help=help)
        if name == command:
            command_parser(p, COMMANDS.get(name))
    return parser


def refuse_moved_flags(p: argparse.ArgumentParser, argv: list[str]) -> None:
    """A flag that was renamed (``eval.config.MOVED_FLAGS``) is refused in one line (exit 2)
    naming the new one, the value given with it."""
    for i, word in enumerate(argv):
        if (new := moved_flag(word)) is not None:
            old, eq, value = word.partition("=")
            value = value if eq else (argv[i + 1] if i + 1 < len(argv) and not argv[i + 1].startswith("-") else "")
            p.exit(2, f"{p.prog}: error: {old} is now {new}: write {' '.join(filter(None, (new, value)))}\n")


# ------------------------------------------------------------------- docs/cli.md's reference table
PAGE_BEGIN, PAGE_END = "<!-- calnav commands -->", "<!-- /calnav commands -->"


def _cell(text: str) -> str:
    """Help text as a Markdown table cell (argparse's %% is %; |, <, * would be Markdown)."""
    return text.replace("%%", "%").replace("|", "\\|").replace("<", "&lt;").replace("*", "\\*")


def commands_table() -> str:
    """Every command and argument as a Markdown table (command | argument | default | what it is),
    from the same declarations ``--help`` prints."""
    rows = ["| command | argument | default | what it is |", "|---|---|---|---|"]
    for name, help in COMMANDS.describe().items():
        command = COMMANDS.get(name)
        ranges = {f.name: f.metadata["range"] for f in command.fields() if f.metadata["range"] is not None}
        rows.append(f"| `calnav {name}` | | | {_cell(help)} |")
        for action in command_parser(argparse.ArgumentParser(prog=f"calnav {name}"), command)._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            spelled = " / ".join(action.option_strings) or action.metavar or action.dest
            if action.option_strings and action.metavar:
                spelled += f" {action.metavar}"
            unset = action.default is None or action.default is False or action.default == [] or action.required
            default = "" if unset else f"`{action.default}`"
            what = _cell(action.help) + (" (required)" if action.required and action.option_strings else "")
            if action.choices:
                what += f"; one of {', '.join(map(str, action.choices))}"
            if action.dest in ranges:
                what += f"; in {ranges[action.dest].text()}"
            rows.append(f"| | `{spelled}` | {default} | {what} |")
    return "\n".join(rows) + "\n"


def render_page(text: str, path: str = "docs/cli.md") -> str:
    """``text`` with its ``PAGE_BEGIN`` ... ``PAGE_END`` block replaced by ``commands_table()``."""
    head, begin, rest = text.partition(PAGE_BEGIN)
    _, end, tail = rest.partition(PAGE_END)
    if not begin or not end:
        raise ValueError(f"{path} has no '{PAGE_BEGIN}' ... '{PAGE_END}' block")
    return f"{head}{PAGE_BEGIN}\n{commands_table()}{PAGE_END}{tail}"


if __name__ == "__main__":   # python -m calnav.eval.parser docs/cli.md: re-render the page's table
    import sys
    from pathlib import Path

    page = Path(sys.argv[1])
    page.write_text(render_page(page.read_text(), str(page)))
