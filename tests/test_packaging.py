"""calnav as a user installs it: a wheel built from this tree, installed into a fresh venv,
run from a directory outside the repository (nothing of the checkout on sys.path). Every
subcommand's --help, a real ObjectNav episode with the shipped config, and the package data
(configs, weights, label maps) found from the installed package."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SKIP = {".git", ".venv", ".venv-habitat", "site", "runs", "build", ".pytest_cache", ".hypothesis", "__pycache__"}

pytestmark = pytest.mark.e2e


def _copy_tree(dst: Path) -> Path:
    """The checkout without venvs, build outputs and results (what a clone holds)."""
    def ignore(folder, names):
        return [n for n in names if n in SKIP or n.endswith(".egg-info")]
    return Path(shutil.copytree(REPO, dst, ignore=ignore))


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(python, calnav, env) of a fresh venv holding only the calnav wheel; its dependencies come
    from the test venv's site-packages through a .pth line (a path line, so that directory's own
    .pth files -- calnav's editable-install hook among them -- are not run)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = _copy_tree(tmp / "src")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
                    "-w", str(tmp / "dist"), str(src)], check=True, capture_output=True, text=True)
    wheel = next((tmp / "dist").glob("calnav-*.whl"))
    venv = tmp / "venv"
    subprocess.run([sys._base_executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    py = venv / "bin" / "python"
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               check=True, capture_output=True, text=True).stdout.strip())
    (site / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q", "--no-deps", str(wheel)],
                   check=True, capture_output=True, text=True)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["CALNAV_CACHE"] = str(tmp / "cache")
    outside = tmp / "elsewhere"
    outside.mkdir()
    return py, venv / "bin" / "calnav", env, outside


def _run(args, env, cwd, timeout=300):
    return subprocess.run([str(a) for a in args], env=env, cwd=cwd, capture_output=True, text=True, timeout=timeout)


def test_the_wheel_holds_every_package_and_its_data(installed):
    py, _, env, cwd = installed
    code = ("import calnav, calnav.eval.cli as cli, importlib, pathlib, sys\n"
            "assert '/venv/' in calnav.__file__ and len(calnav.__path__) == 1, (calnav.__file__, calnav.__path__)\n"
            "for name in cli.COMMANDS:\n"
            "    cli.COMMANDS.get(name)\n"   # every command's module and config loader imports
            "from calnav.eval.config import load_config\n"
            "from calnav.eval.config import CALIBRATION_SECTIONS\n"
            "load_config('configs/objectnav.yaml'); load_config('calibrate_map.yaml', sections=CALIBRATION_SECTIONS)\n"
            "from calnav.agent.segmenters import check_segmenter\n"
            "assert len(check_segmenter('learned_rgb')) == 18 and len(check_segmenter('learned_rgbd')) == 18\n"
            "from calnav.agent.segmenters.label_map import BUILTIN_LABEL_MAPS, read_label_map\n"
            "assert [len(read_label_map(m).model_classes) for m in BUILTIN_LABEL_MAPS] == [150, 40, 20, 133]\n"
            "from calnav.mapping.glfs import GLFSParams\n"
            "GLFSParams.load('agent/weights/glfs_learned_rgb.json')\n"
            "import calnav.mapping.sequences, calnav.eval.sequence, calnav.envs.scanning\n"
            "print('ok')\n")
    out = _run([py, "-c", code], env, cwd)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]


# every subcommand's --help through the installed package's main, in one interpreter (one
# process start, not one per subcommand); each exits 0 and prints calnav's usage
HELP_ALL = ("import contextlib, io, sys\n"
            "from calnav.eval.cli import COMMANDS, main\n"
            "for name in COMMANDS:\n"
            "    out = io.StringIO()\n"
            "    with contextlib.redirect_stdout(out):\n"
            "        try:\n"
            "            main([name, '--help'])\n"
            "            code = 'no exit'\n"
            "        except SystemExit as exc:\n"
            "            code = exc.code\n"
            "    print(name, code, 'usage: calnav' in out.getvalue())\n")


def test_every_subcommand_answers_help_from_outside_the_repository(installed):
    py, calnav, env, cwd = installed
    out = _run([py, "-c", HELP_ALL], env, cwd)
    assert out.returncode == 0, out.stderr[-2000:]
    answers = [line.split() for line in out.stdout.splitlines()]
    assert len(answers) >= 15
    for name, code, usage in answers:
        assert code == "0" and usage == "True", (name, code, usage)
    # the installed console script and ``python -m calnav`` themselves, as a user starts them
    first = answers[0][0]
    out = _run([calnav, first, "--help"], env, cwd)
    assert out.returncode == 0 and f"usage: calnav {first}" in out.stdout, out.stderr[-1000:]
    assert _run([py, "-m", "calnav", "--help"], env, cwd).returncode == 0


def test_an_objectnav_episode_with_the_shipped_config_from_outside(installed):
    _, calnav, env, cwd = installed
    out = _run([calnav, "objectnav", "--agent", "oracle", "--episodes", "0:1", "--output", cwd / "run"], env, cwd)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "| oracle | 1.000" in out.stdout and (cwd / "run" / "episodes.jsonl").is_file()
