"""The public surface of every top-level package: one re-export style, a version, no global side effects, no cycles.

Every package ``__init__.py`` re-exports its private modules' names explicitly (``from ._module import name as
name``), with no ``import *`` and no ``__all__`` list, and ends with ``__version__``. Importing the packages must
leave the process as it found it: no XLA flags written, no 64-bit mode switched on, no matplotlib backend chosen,
and jax's backend not initialised (so an entry point can still call ``geometry.disable_faulty_cpu_fusion()``).
"""

import ast
import importlib
import importlib.metadata
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("geometry", "mocap", "training", "structri", "jcsat", "flex", "dynamics", "association")
PRESENT = tuple(p for p in PACKAGES if (REPO / p / "__init__.py").is_file())


def _init_source(package: str) -> ast.Module:
    return ast.parse((REPO / package / "__init__.py").read_text())


def _run(code: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=REPO,
                          env={**os.environ, "PYTHONPATH": str(REPO), **(env or {})})


def _private_modules(package: str) -> list[str]:
    return [f"{package}.{m.stem}" for m in sorted((REPO / package).glob("_*.py")) if m.stem != "__init__"]


@pytest.mark.parametrize("package", PRESENT)
def test_version_is_the_installed_distributions(package):
    assert importlib.import_module(package).__version__ == importlib.metadata.version("mvmocap")


@pytest.mark.parametrize("package", PRESENT)
def test_init_reexports_explicitly(package):
    """A docstring, then only ``from ._module import name as name`` (and the version import), no ``__all__``."""
    tree = _init_source(package)
    assert ast.get_docstring(tree), f"{package}/__init__.py has no module docstring"
    problems = []
    for node in tree.body[1:]:
        if isinstance(node, ast.ImportFrom) and node.module == "importlib.metadata":
            if [(a.name, a.asname) for a in node.names] != [("version", "_version")]:
                problems.append(f"line {node.lineno}: import only `version as _version` from importlib.metadata")
        elif isinstance(node, ast.ImportFrom):
            if node.level != 1 or not (node.module or "").startswith("_"):
                problems.append(f"line {node.lineno}: re-export from a private module of the package")
            problems += [f"line {node.lineno}: `{a.name}` re-exported without `as {a.name}`"
                         for a in node.names if a.name == "*" or a.asname != a.name]
        elif isinstance(node, ast.Assign) and [getattr(t, "id", None) for t in node.targets] == ["__version__"]:
            if ast.unparse(node.value) != "_version('mvmocap')":
                problems.append(f"line {node.lineno}: __version__ must be _version('mvmocap')")
        else:
            problems.append(f"line {node.lineno}: `{ast.unparse(node)[:60]}` is neither a re-export nor the version")
    names = {t.id for node in tree.body if isinstance(node, ast.Assign) for t in node.targets if hasattr(t, "id")}
    assert "__version__" in names, f"{package}/__init__.py sets no __version__"
    assert not problems, f"{package}/__init__.py: " + "; ".join(problems)


@pytest.mark.parametrize("package", PRESENT)
def test_init_reexports_every_public_name_of_its_modules(package):
    """Each private module's ``__all__`` is re-exported whole, and nothing else is."""
    expected = set()
    for module in _private_modules(package):
        path = REPO / package / f"{module.split('.')[1]}.py"
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.Assign) and [getattr(t, "id", None) for t in node.targets] == ["__all__"]:
                expected |= {(path.stem, name) for name in ast.literal_eval(node.value)}
    exported = {(node.module, a.name) for node in _init_source(package).body
                if isinstance(node, ast.ImportFrom) and node.level == 1 for a in node.names}
    assert exported == expected, (f"missing {sorted(expected - exported)}, "
                                  f"not in any __all__ {sorted(exported - expected)}")


@pytest.mark.parametrize("package", PRESENT)
def test_importing_the_package_changes_no_global_state(package):
    """In a fresh interpreter: XLA flags, 64-bit mode, the matplotlib backend and jax's backend state are the same
    after importing the package (and all it imports) as before."""
    code = f"""
import json, os
import jax, matplotlib
from jax._src import xla_bridge
state = lambda: {{"XLA_FLAGS": os.environ.get("XLA_FLAGS"), "x64": bool(jax.config.jax_enable_x64),
                 "backend": matplotlib.rcParams._get_backend_or_none(),
                 "jax initialised": xla_bridge.backends_are_initialized()}}
before = state()
import {package}
print(json.dumps([before, state()]))
"""
    done = _run(code, {"XLA_FLAGS": "", "JAX_ENABLE_X64": "0", "MPLBACKEND": ""})  # as a fresh shell has them
    assert done.returncode == 0, done.stderr
    before, after = json.loads(done.stdout.splitlines()[-1])
    assert after == before


def _module_imports(module: str) -> set[str]:
    """The sibling private modules ``module`` imports anywhere in its source (relative or absolute)."""
    package = module.split(".")[0]
    tree = ast.parse(Path(importlib.util.find_spec(module).origin).read_text())
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module:
            found.add(f"{package}.{node.module.split('.')[0]}")
        elif isinstance(node, ast.ImportFrom) and node.level == 1:
            found |= {f"{package}.{a.name}" for a in node.names}
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith(f"{package}._"):
            found.add(".".join(node.module.split(".")[:2]))
    return found & set(_private_modules(package))


@pytest.mark.parametrize("package", ["geometry", "mocap", "training"])
def test_private_modules_import_each_other_without_cycles(package):
    """The graph of which private module imports which (function-level imports included) is acyclic."""
    graph = {m: _module_imports(m) for m in _private_modules(package)}
    done, on_path = set(), []

    def visit(module):
        if module in on_path:
            cycle = on_path[on_path.index(module):] + [module]
            pytest.fail(f"import cycle: {' -> '.join(cycle)}")
        if module in done:
            return
        on_path.append(module)
        for imported in sorted(graph[module]):
            visit(imported)
        on_path.pop()
        done.add(module)

    for module in graph:
        visit(module)
