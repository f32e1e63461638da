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
- no package has an import cycle between its modules;
- inside ``eval`` (one node per experiment subpackage or top-level module):

  - the top, ``eval.cli`` (parsing and dispatch) and ``eval.preflight`` (loads every command's
    configs), may import anything of ``eval``; only ``eval.cli`` imports ``eval.preflight`` and
    nothing imports ``eval.cli``;
  - the shared modules (``config``, ``results_dir``, ``backends``, ``stats``, ``episodes``) import no
    experiment subpackage and not the top;
  - an experiment subpackage imports the shared modules and only the experiment subpackages
    ``EVAL_ALLOWED`` declares for it: a new cross-import fails until it is declared there;
  - neither the imports nor the declared table have a cycle between the nodes;
  - every subpackage and top-level module of ``eval`` is classified (a new one must be).
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


def _imports(path: Path, raw: bool = False) -> set[str]:
    """Absolute module names imported anywhere in ``path`` (``from a import b`` gives ``a`` and
    ``a.b``, as b may be a submodule), named inside calnav (``calnav.mapping.fusion`` ->
    ``mapping.fusion``) unless ``raw``. Relative imports stay inside their package: skipped."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module)
            out.update(f"{node.module}.{alias.name}" for alias in node.names if alias.name != "*")
    return out if raw else {name.removeprefix("calnav.") for name in out}


def _package_files(package: str) -> dict[str, set[str]]:
    """{module name: imported module names} of every .py file of ``package``."""
    return {_module_name(p): _imports(p) for p in sorted((REPO_ROOT / package).rglob("*.py"))}


def test_project_modules_are_imported_as_calnav_subpackages():
    """Installed, the packages live under ``calnav`` (``calnav.mapping``): a bare ``import mapping``
    would find another distribution's ``mapping`` or nothing."""
    bad = sorted(f"{path.relative_to(REPO_ROOT)} imports {name}"
                 for path in sorted(REPO_ROOT.glob("*/**/*.py")) if path.parts[len(REPO_ROOT.parts)] != ".venv"
                 and path.parts[len(REPO_ROOT.parts)] in PACKAGES + ("tests",)
                 for name in _imports(path, raw=True) if _top(name) in PACKAGES)
    assert not bad, "import them as calnav.<package>:\n" + "\n".join(bad)


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


def _find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` ({node: nodes it depends on}) as [a, b, ..., a], or None."""
    done: set[str] = set()

    def visit(node: str, path: list[str]) -> list[str] | None:
        for dep in sorted(graph.get(node, ())):
            if dep in path:
                return path[path.index(dep):] + [dep]
            if dep not in done and (cycle := visit(dep, path + [dep])):
                return cycle
        done.add(node)
        return None

    for node in sorted(graph):
        if cycle := visit(node, [node]):
            return cycle
    return None


def test_no_import_cycles(sources):
    # edges between modules of one package; `from mapping import fusion` also names the package
    # ``mapping`` itself, an ancestor that is always initialised first: not an edge
    graph = {mod: {d for d in deps if d in sources[pkg] and d != mod and not mod.startswith(d + ".")}
             for pkg in PACKAGES for mod, deps in sources[pkg].items()}
    assert len(graph) > 100
    cycle = _find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_find_cycle_finds_one():
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert _find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


# ------------------------------------------------------------------------------------- eval
# One node per experiment subpackage (eval/<name>/) and per top-level module (eval/<name>.py).
EVAL_TOP = {"cli", "parser", "preflight"}                            # may import anything of eval
EVAL_SHARED = {"config", "validation", "sections", "shorthands", "arguments", "results_dir", "records", "inputs",
               "backends", "runner", "stats", "episodes", "memory", "rollout"}  # import only each other
# experiment subpackage -> the experiment subpackages it may import (the shared modules always).
# Declaring a new edge here must keep the table acyclic (test_eval_dependency_table_is_acyclic).
EVAL_ALLOWED: dict[str, set[str]] = {
    "bench": {"objectnav",     # bench.backends, bench.start_pose time ObjectNav runs and the frame study
              "sequence",      # bench.sequence times ScanNet export and the recorded-sequence map
              "segmenter"},    # bench.adapter times calnav's learned_rgb exported to ONNX
    "calibration": set(),
    "habitat": {"objectnav"},  # the habitat benchmark reuses objectnav.run's bookkeeping and report
    "objectnav": set(),
    "prediction": {"objectnav"},  # collect-maps runs the agent on objectnav.run's warm env / agent workers
    "scanning": set(),
    "segmenter": set(),
    "sequence": {"calibration"},  # export-sequence writes a calibration scan (HouseScan, scene_seed);
                                  # `calnav map` draws calibration.plots' diagrams
}


def _eval_node(module: str) -> str | None:
    """The eval node of a module name (``eval.objectnav.run.main`` -> ``objectnav``); None for
    ``eval`` itself and outside eval."""
    parts = module.split(".")
    return parts[1] if parts[0] == "eval" and len(parts) > 1 else None


@pytest.fixture(scope="module")
def eval_edges(sources) -> list[tuple[str, str, str, str]]:
    """(node, node imported, module, module imported) of every import between two eval nodes."""
    return sorted((src, dst, mod, dep) for mod, deps in sources["eval"].items() for dep in deps
                  if (src := _eval_node(mod)) and (dst := _eval_node(dep)) and dst != src)


def test_every_eval_part_is_classified(sources, eval_edges):
    root = REPO_ROOT / "eval"
    found = {p.name for p in root.iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    found |= {p.stem for p in root.glob("*.py") if p.stem != "__init__"}
    assert found == EVAL_TOP | EVAL_SHARED | set(EVAL_ALLOWED), \
        f"classify in EVAL_TOP / EVAL_SHARED / EVAL_ALLOWED: {sorted(found ^ (EVAL_TOP | EVAL_SHARED | set(EVAL_ALLOWED)))}"
    assert not (EVAL_TOP & EVAL_SHARED) and not ((EVAL_TOP | EVAL_SHARED) & set(EVAL_ALLOWED))
    assert all(deps <= set(EVAL_ALLOWED) for deps in EVAL_ALLOWED.values())
    assert {_eval_node(m) for m in sources["eval"]} - {None} == found
    # the scan sees cross-node imports of each kind: experiment -> shared, experiment -> experiment, top -> experiment
    kinds = {(src in EVAL_ALLOWED, dst in EVAL_ALLOWED, src in EVAL_TOP) for src, dst, _, _ in eval_edges}
    assert {(True, False, False), (True, True, False), (False, True, True)} <= kinds, kinds


def test_eval_shared_modules_import_no_experiment(eval_edges):
    bad = [f"{mod} imports {dep}" for src, dst, mod, dep in eval_edges
           if src in EVAL_SHARED and dst not in EVAL_SHARED]
    assert not bad, f"the shared modules {sorted(EVAL_SHARED)} import only each other:\n" + "\n".join(bad)


def test_eval_experiments_import_only_declared_experiments(eval_edges):
    bad = [f"{mod} imports {dep}" for src, dst, mod, dep in eval_edges
           if src in EVAL_ALLOWED and dst not in EVAL_SHARED | EVAL_ALLOWED[src]]
    assert not bad, ("an undeclared import between eval's parts: declare the edge in EVAL_ALLOWED "
                     "(keeping it acyclic) or move the shared code to a shared module:\n" + "\n".join(bad))


def test_only_the_cli_imports_preflight_and_nothing_imports_the_cli(eval_edges):
    bad = [f"{mod} imports {dep}" for src, dst, mod, dep in eval_edges
           if dst == "cli" or (dst == "preflight" and src != "cli")]
    assert not bad, "\n".join(bad)


def test_no_import_cycles_between_eval_parts(eval_edges):
    graph: dict[str, set[str]] = {}
    for src, dst, _, _ in eval_edges:
        graph.setdefault(src, set()).add(dst)
    assert len(graph) >= len(EVAL_ALLOWED)
    cycle = _find_cycle(graph)
    where = [f"{mod} imports {dep}" for src, dst, mod, dep in eval_edges
             if cycle and (src, dst) in zip(cycle, cycle[1:])]
    assert cycle is None, "import cycle between eval's parts: " + " -> ".join(cycle or []) + "\n" + "\n".join(where)


def test_eval_dependency_table_is_acyclic():
    cycle = _find_cycle(EVAL_ALLOWED)
    assert cycle is None, "EVAL_ALLOWED declares a cycle: " + " -> ".join(cycle or [])


# habitat-lab (numpy 1.26 only, its own venv) is imported by these modules and no others, so
# `import envs` / `import agent` / the CLI never need it
HABITAT_MODULES = {"common.habitat_import", "envs.habitat_sim_backend", "envs.habitat_config", "agent.habitat_agent",
                   "eval.habitat.recording", "eval.habitat.run"}


def test_only_the_habitat_modules_import_habitat(sources):
    users = {mod for pkg in PACKAGES for mod, deps in sources[pkg].items()
             if any(_top(d) in ("habitat", "habitat_sim") for d in deps)}
    assert users and users <= HABITAT_MODULES, sorted(users - HABITAT_MODULES)


def test_importing_the_packages_does_not_import_habitat():
    import subprocess
    import sys

    code = ("import sys, calnav.envs, calnav.envs.objectnav_env, calnav.agent.policy, calnav.eval.cli, "
            "calnav.eval.habitat.run; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('habitat', 'habitat_sim')))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO_ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
