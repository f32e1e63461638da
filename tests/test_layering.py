"""Package layering, checked on the source (every import statement anywhere in a file, including
function-local and ``TYPE_CHECKING`` imports), anchored at the repository root so the result does
not depend on the working directory:

- ``common`` imports no project package (everything may import it);
- ``mapping`` imports neither ``agent`` nor ``envs`` nor ``eval``;
- ``envs`` imports none of ``agent``, ``mapping``, ``eval``;
- ``agent`` does not import ``eval``, and of ``envs`` only the task interface (``envs.task``,
  ``envs.semantics``), never the simulator's internals;
- the online map (``mapping`` outside ``mapping.calibration``) does not import the offline
  calibration package;
- ``common``, ``envs`` and ``mapping`` have no import cycles between their modules.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("common", "envs", "mapping", "agent", "eval")

FORBIDDEN = {
    "common": {"agent", "envs", "mapping", "eval"},
    "mapping": {"agent", "envs", "eval"},
    "envs": {"agent", "mapping", "eval"},
    "agent": {"eval"},
}
AGENT_ALLOWED_ENVS = {"envs.task", "envs.semantics"}
# a module every package must contain: proves the scan looked in the right place
LANDMARKS = {"common": "common.npz", "envs": "envs.scene", "mapping": "mapping.fusion",
             "agent": "agent.policy", "eval": "eval.cli"}


def _module_name(path: Path) -> str:
    parts = path.relative_to(REPO_ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """Absolute module names imported anywhere in ``path`` (``from a import b`` gives ``a`` and
    ``a.b``, as b may be a submodule). Relative imports stay inside their package: skipped."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module)
            out.update(f"{node.module}.{alias.name}" for alias in node.names if alias.name != "*")
    return out


def _package_files(package: str) -> dict[str, set[str]]:
    """{module name: imported module names} of every .py file of ``package``."""
    return {_module_name(p): _imports(p) for p in sorted((REPO_ROOT / package).rglob("*.py"))}


@pytest.fixture(scope="module")
def sources() -> dict[str, dict[str, set[str]]]:
    return {pkg: _package_files(pkg) for pkg in PACKAGES}


def _top(module: str) -> str:
    return module.split(".", 1)[0]


def test_the_scan_finds_every_package(sources):
    for pkg in PACKAGES:
        assert (REPO_ROOT / pkg / "__init__.py").is_file(), f"{pkg} is not a package under {REPO_ROOT}"
        assert LANDMARKS[pkg] in sources[pkg], f"{LANDMARKS[pkg]} not found among {sorted(sources[pkg])[:10]}"
    for pkg in ("envs", "mapping", "agent", "eval"):  # the scan sees their imports of themselves
        assert any(_top(m) == pkg for deps in sources[pkg].values() for m in deps), f"no {pkg} import seen in {pkg}"


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_package_imports_respect_the_layering(sources, package):
    bad = sorted(f"{mod} imports {dep}" for mod, deps in sources[package].items()
                 for dep in deps if _top(dep) in FORBIDDEN[package])
    assert not bad, f"{package} must import none of {sorted(FORBIDDEN[package])}:\n" + "\n".join(bad)


def test_agent_imports_no_simulator_internals(sources):
    bad = sorted(f"{mod} imports {dep}" for mod, deps in sources["agent"].items() for dep in deps
                 if _top(dep) == "envs" and dep not in AGENT_ALLOWED_ENVS
                 and dep.rsplit(".", 1)[0] not in AGENT_ALLOWED_ENVS)  # `from envs.task import Action`
    assert not bad, f"agent may import only {sorted(AGENT_ALLOWED_ENVS)} of envs:\n" + "\n".join(bad)


def test_online_map_does_not_import_the_calibration_package(sources):
    online = {m: deps for m, deps in sources["mapping"].items() if not m.startswith("mapping.calibration")}
    assert "mapping.voxel_map" in online and "mapping.fusion" in online
    bad = sorted(f"{mod} imports {dep}" for mod, deps in online.items() for dep in deps
                 if dep == "mapping.calibration" or dep.startswith("mapping.calibration."))
    assert not bad, "\n".join(bad)


def test_no_import_cycles(sources):
    # edges between modules of one package; `from mapping import fusion` also names the package
    # ``mapping`` itself, an ancestor that is always initialised first: not an edge
    graph = {mod: {d for d in deps if d in sources[pkg] and d != mod and not mod.startswith(d + ".")}
             for pkg in ("common", "envs", "mapping") for mod, deps in sources[pkg].items()}
    assert len(graph) > 20
    done: set[str] = set()

    def visit(mod: str, path: list[str]) -> None:
        for dep in sorted(graph.get(mod, ())):
            if dep in path:
                pytest.fail("import cycle: " + " -> ".join(path[path.index(dep):] + [dep]))
            elif dep not in done:
                visit(dep, path + [dep])
        done.add(mod)

    for mod in sorted(graph):
        visit(mod, [mod])


# habitat-lab (numpy 1.26 only, its own venv) is imported by these modules and no others, so
# `import envs` / `import agent` / the CLI never need it
HABITAT_MODULES = {"common.habitat_import", "envs.habitat_sim_backend", "envs.habitat_config", "agent.habitat_agent",
                   "eval.habitat.agents", "eval.habitat.recording", "eval.habitat.run"}


def test_only_the_habitat_modules_import_habitat(sources):
    users = {mod for pkg in PACKAGES for mod, deps in sources[pkg].items()
             if any(_top(d) in ("habitat", "habitat_sim") for d in deps)}
    assert users and users <= HABITAT_MODULES, sorted(users - HABITAT_MODULES)


def test_importing_the_packages_does_not_import_habitat():
    import subprocess
    import sys

    code = ("import sys, envs, envs.objectnav_env, agent.policy, eval.cli, eval.habitat.run; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('habitat', 'habitat_sim')))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
