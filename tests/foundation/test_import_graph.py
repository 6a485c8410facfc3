"""The import graph goes one way, and the light packages never load torch."""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("api", "client", "server", "worker", "engine")
# Which of our packages each package may import.
ALLOWED: dict[str, set[str]] = {
    "api": {"api"},
    "client": {"client", "api"},
    "server": {"server", "api"},
    "worker": {"worker", "api", "engine"},
    "engine": {"engine", "api"},
}
# The engine may import six light parts of api, each shared with the torch-free SDK so that
# one definition serves both: the pure-pydantic camera schemas (one schema validates
# cameras.json and render cameras everywhere), the camera estimation's report (written by the
# engine, carried by a job), the render schemas (render modes, live-view frames), the native
# kernels' build status file (written by the engine's build, read by the torch-free server),
# the scene-format readers (file layouts, splits, pose conventions; the
# engine wraps them into torch Scenes), and the shared names. Settings, logging, job and store
# modules stay out of the engine. Each entry covers the module or package and everything below it.
ENGINE_MAY_IMPORT_FROM_API = {
    "sparsesplat.api.cameras",
    "sparsesplat.api.camera_estimation",
    "sparsesplat.api.scenes",
    "sparsesplat.api.names",
    "sparsesplat.api.renders",
    "sparsesplat.api.kernel_status",
}
# What those api modules may import besides the standard library (NumPy only inside the
# functions that need it: the base SDK install, which has no NumPy, reads the JSON formats),
# and which of our modules. The shared names (job states, training choices, artifact files)
# are plain literals: standard library only.
LIGHT_DEPENDENCIES = {
    "sparsesplat.api.cameras": {"pydantic"},
    "sparsesplat.api.camera_estimation": {"pydantic"},
    "sparsesplat.api.scenes": {"numpy"},
    "sparsesplat.api.names": set(),
    "sparsesplat.api.renders": {"pydantic"},
    "sparsesplat.api.kernel_status": {"pydantic"},
}
# Modules a package loads by name string (importlib.import_module / __import__) that cross the
# layering on purpose: the ``sparsesplat render`` command renders a local checkpoint through
# the engine's command when the engine extra is installed (MissingExtra otherwise).
DISPATCH_BY_NAME = {("client/commands/render.py", "sparsesplat.engine.commands.render")}


def _module_constants(tree: ast.Module) -> dict[str, str]:
    """Module-level ``NAME = "string"`` assignments (a module name kept in a constant)."""
    found: dict[str, str] = {}
    for node in tree.body:
        value = node.value if isinstance(node, ast.Assign | ast.AnnAssign) else None
        if isinstance(value, ast.Constant) and isinstance(value.value, str):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            found.update({t.id: value.value for t in targets if isinstance(t, ast.Name)})
    return found


def _imported_by_name(tree: ast.Module) -> list[str]:
    """Modules loaded by name string: ``importlib.import_module(X)``, ``import_module(X)`` or
    ``__import__(X)`` where X is a string literal, a module-level string constant, or an
    f-string (its literal prefix up to the first placeholder)."""
    constants = _module_constants(tree)
    found: list[str] = []
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and node.args):
            continue
        func = node.func
        name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
        if name not in ("import_module", "__import__"):
            continue
        arg = node.args[0]
        if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
            found.append(arg.value)
        elif isinstance(arg, ast.Name) and arg.id in constants:
            found.append(constants[arg.id])
        elif isinstance(arg, ast.JoinedStr) and arg.values:
            head = arg.values[0]
            if isinstance(head, ast.Constant) and isinstance(head.value, str):
                found.append(head.value.rstrip("."))
    return found


def _imported_modules(path: Path, by_name: bool = True) -> list[tuple[str, int]]:
    """Every absolute module ``path`` imports, with ``from X import y`` also giving ``X.y``
    (y may be a submodule); relative imports are returned with their level. With
    ``by_name``, modules loaded by name string count too (:func:`_imported_by_name`)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found: list[tuple[str, int]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, 0) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            found.append((module, node.level))
            found += [(f"{module}.{alias.name}", node.level) for alias in node.names]
    if by_name:
        rel = str(path.relative_to(REPO)) if path.is_relative_to(REPO) else path.name
        found += [(m, 0) for m in _imported_by_name(tree) if (rel, m) not in DISPATCH_BY_NAME]
    return found


def _our_imports(path: Path, package: str) -> set[str]:
    """Packages of ours that ``path`` imports (absolute ``sparsesplat.X`` or relative)."""
    found: set[str] = set()
    for name, level in _imported_modules(path):
        if level:  # relative import stays inside the package
            found.add(package)
            continue
        parts = name.split(".")
        if parts[0] == "sparsesplat" and len(parts) > 1 and parts[1] in PACKAGES:
            found.add(parts[1])
        elif parts[0] in PACKAGES:
            pytest.fail(f"{path.relative_to(REPO)} imports bare '{name}'; use 'sparsesplat.{name}'")
    return found


@pytest.mark.parametrize("package", PACKAGES)
def test_imports_follow_the_layering(package: str) -> None:
    violations = []
    for path in sorted((REPO / package).rglob("*.py")):
        bad = _our_imports(path, package) - ALLOWED[package]
        if bad:
            violations.append(f"{path.relative_to(REPO)} imports {sorted(bad)}")
    assert not violations, "layering violated:\n" + "\n".join(violations)


def _allowed_in_engine(module: str) -> str | None:
    """The :data:`ENGINE_MAY_IMPORT_FROM_API` entry covering ``module``, else None."""
    for allowed in ENGINE_MAY_IMPORT_FROM_API:
        if module == allowed or module.startswith(allowed + "."):
            return allowed
    return None


def _api_modules_imported_by_engine(root: Path = REPO / "engine") -> dict[str, set[str]]:
    """``sparsesplat.api...`` module -> engine files importing it (``from M import x`` counts
    as ``M``: x may be a function as well as a submodule)."""
    used: dict[str, set[str]] = {}
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        names = [
            alias.name for n in ast.walk(tree) if isinstance(n, ast.Import) for alias in n.names
        ]
        names += [
            n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and not n.level
        ]
        names += _imported_by_name(tree)
        for name in names:
            if name == "sparsesplat.api" or name.startswith("sparsesplat.api."):
                used.setdefault(name, set()).add(str(path.relative_to(root.parent)))
    return used


def test_engine_imports_only_the_light_modules_of_api() -> None:
    used = _api_modules_imported_by_engine()
    bad = {m: sorted(files) for m, files in used.items() if _allowed_in_engine(m) is None}
    assert not bad, f"engine may import only {sorted(ENGINE_MAY_IMPORT_FROM_API)} from api: {bad}"
    # The rule is live, not vacuous: the folder loader validates through the api schema and the
    # format loaders read through the shared scene readers.
    assert "engine/datasets/folder.py" in used.get("sparsesplat.api.cameras", set())
    assert any(m.startswith("sparsesplat.api.scenes") for m in used)


def _light_modules() -> list[str]:
    """Every module under the :data:`ENGINE_MAY_IMPORT_FROM_API` entries."""
    modules = []
    for entry in sorted(ENGINE_MAY_IMPORT_FROM_API):
        base = REPO / Path(*entry.split(".")[1:])
        files = sorted(base.rglob("*.py")) if base.is_dir() else [base.with_suffix(".py")]
        for path in files:
            parts = ["sparsesplat", *path.relative_to(REPO).with_suffix("").parts]
            modules.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return modules


@pytest.mark.parametrize("module", _light_modules())
def test_api_modules_the_engine_imports_stay_light(module: str) -> None:
    """Statically: stdlib, the entry's own dependency and its own package only; at run time:
    no torch, NumPy, web stack or anything of ours beyond api."""
    entry = _allowed_in_engine(module)
    assert entry is not None
    relative = Path(*module.split(".")[1:])
    path = REPO / relative / "__init__.py"
    path = path if path.is_file() else (REPO / relative).with_suffix(".py")
    heavy = []
    for name, level in _imported_modules(path):
        top = name.split(".")[0]
        if level or top == "__future__" or top in sys.stdlib_module_names:
            continue
        light = any(name == m or name.startswith(m + ".") for m in ENGINE_MAY_IMPORT_FROM_API)
        if top not in LIGHT_DEPENDENCIES[entry] and not light:
            heavy.append(name)
    allowed = sorted(LIGHT_DEPENDENCIES[entry])
    assert not heavy, f"{module} imports beyond stdlib + {allowed}: {sorted(set(heavy))}"
    watched = ("torch", "numpy", "fastapi", "httpx", "starlette", "pydantic_settings")
    code = (
        f"import sys, importlib; importlib.import_module({module!r}); "
        f"print(sorted(m for m in sys.modules if m.split('.')[0] in {watched!r} "
        "or (m.startswith('sparsesplat.') and not m.startswith('sparsesplat.api'))))"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.strip() == "[]", f"{module} pulled in: {result.stdout.strip()}"


def test_the_engine_api_rule_can_fail(tmp_path: Path) -> None:
    """Guard against a vacuous rule: engine-style imports of api.settings (plain, by name
    string, through a constant) and of a module merely named like an allowed one are caught."""
    probe = tmp_path / "probe.py"
    probe.write_text(
        "import importlib\n"
        "from sparsesplat.api.settings import Settings\n"
        "import sparsesplat.api.logs\n"
        "STORE = 'sparsesplat.api.store.jobs'\n"
        "importlib.import_module('sparsesplat.api.jobs')\n"
        "importlib.import_module(STORE)\n"
        "__import__('sparsesplat.api.scenesque')\n"
        "from sparsesplat.api.scenes.splits import llff_split\n"
    )
    used = _api_modules_imported_by_engine(tmp_path)
    bad = {m for m in used if _allowed_in_engine(m) is None}
    assert bad == {
        "sparsesplat.api.settings",
        "sparsesplat.api.logs",
        "sparsesplat.api.jobs",
        "sparsesplat.api.store.jobs",
        "sparsesplat.api.scenesque",
    }
    assert _allowed_in_engine("sparsesplat.api.scenes.splits") == "sparsesplat.api.scenes"


def test_the_layering_rule_sees_imports_by_name_string(tmp_path: Path) -> None:
    """A client module that loads the engine through importlib, directly, through a module
    constant or an f-string, breaks the layering like a plain import would; the one
    documented dispatch (:data:`DISPATCH_BY_NAME`) is the only exception."""
    probe = tmp_path / "probe.py"
    probe.write_text(
        "import importlib\n"
        "ENGINE = 'sparsesplat.engine.train'\n"
        "def load(kind):\n"
        "    importlib.import_module(ENGINE)\n"
        "    __import__('sparsesplat.worker.cli')\n"
        "    return importlib.import_module(f'sparsesplat.server.{kind}')\n"
    )
    assert _our_imports(probe, "client") - ALLOWED["client"] == {"engine", "worker", "server"}
    assert not _our_imports(probe, "worker") - ALLOWED["worker"] - {"server"}
    render = REPO / "client" / "commands" / "render.py"
    assert "sparsesplat.engine.commands.render" in _imported_by_name(ast.parse(render.read_text()))
    assert "engine" not in _our_imports(render, "client")


_BLOCK_TORCH = """
import importlib, pkgutil, sys
class BlockTorch:
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ImportError(f"torch import attempted while importing light packages: {{name}}")
        return None
sys.meta_path.insert(0, BlockTorch())
import sparsesplat
failed = []
for pkg in {packages!r}:
    mod = importlib.import_module(f"sparsesplat.{{pkg}}")
    for info in pkgutil.walk_packages(mod.__path__, prefix=f"sparsesplat.{{pkg}}."):
        # Alembic migration scripts (env.py, versions/) run only inside alembic's context.
        if ".migrations" in info.name:
            continue
        importlib.import_module(info.name)
assert "torch" not in sys.modules
print("ok")
"""


def test_light_packages_never_import_torch() -> None:
    """Every module of api/, client/ and server/ imports with torch made unimportable."""
    code = _BLOCK_TORCH.format(packages=("api", "client", "server"))
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.strip().endswith("ok")


def test_the_torch_check_can_fail() -> None:
    """Guard against a vacuous check: importing the engine under the same blocker must fail."""
    code = _BLOCK_TORCH.format(packages=("engine",))
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert result.returncode != 0
    assert "torch import attempted" in result.stderr


def _module_name(path: Path, root: Path) -> str:
    """The dotted name ``path`` imports as (a package folder's ``sparsesplat.`` prefix added)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[0] in PACKAGES:
        parts = ["sparsesplat", *parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _runtime_imports(path: Path, module: str) -> list[tuple[str, str]]:
    """Every module ``path`` imports when it runs: at module level and inside functions alike
    (a lazy import closes a circle as surely, only later), but not under ``if
    TYPE_CHECKING:`` (never executed). Each as (``X.y``, ``X``) for ``from X import y``: the
    submodule ``X.y`` where y is one, else ``X`` itself (y is a name its ``__init__`` defines;
    a parent package is loaded before any module in it, so it closes no circle by that)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    found: list[tuple[str, str]] = []

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                for stmt in child.orelse:
                    visit_stmt(stmt)
                continue
            visit_stmt(child)

    def visit_stmt(child: ast.AST) -> None:
        if isinstance(child, ast.Import):
            found.extend((alias.name, alias.name) for alias in child.names)
        elif isinstance(child, ast.ImportFrom):
            base = child.module or ""
            if child.level:
                head = package[: len(package) - (child.level - 1)]
                base = ".".join([*head, *([child.module] if child.module else [])])
            found.extend((f"{base}.{alias.name}", base) for alias in child.names)
        else:
            visit(child)

    visit(tree)
    return found


def _import_graph(root: Path, folders: Sequence[str]) -> dict[str, set[str]]:
    """Module -> the modules of ours it imports at run time (:func:`_runtime_imports`)."""
    files = {
        _module_name(path, root): path
        for folder in folders
        for path in sorted((root / folder).rglob("*.py"))
        if "migrations" not in path.parts  # alembic's scripts run inside alembic only
    }
    graph: dict[str, set[str]] = {}
    for module, path in files.items():
        targets = {sub if sub in files else base for sub, base in _runtime_imports(path, module)}
        graph[module] = (targets & files.keys()) - {module}
    return graph


def _import_circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan's algorithm): each is at
    least one import circle."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    circles: list[list[str]] = []

    def connect(module: str) -> None:
        index[module] = low[module] = len(index)
        stack.append(module)
        for target in sorted(graph[module]):
            if target not in index:
                connect(target)
                low[module] = min(low[module], low[target])
            elif target in stack:
                low[module] = min(low[module], index[target])
        if low[module] == index[module]:
            group = []
            while True:
                member = stack.pop()
                group.append(member)
                if member == module:
                    break
            if len(group) > 1:
                circles.append(sorted(group))

    for module in sorted(graph):
        if module not in index:
            connect(module)
    return circles


def test_no_import_circles() -> None:
    """No module of ours imports itself back through others, lazily inside a function or not
    (imports under TYPE_CHECKING aside): each concept's home sits above the code that uses
    it, so any module can be imported first."""
    graph = _import_graph(REPO, (*PACKAGES, "benchmarks"))
    assert len(graph) > 200  # the walk found the tree
    circles = _import_circles(graph)
    described = [
        " -> ".join(group) + "  (" + "; ".join(
            f"{m} imports {sorted(graph[m] & set(group))}" for m in group
        ) + ")"
        for group in circles
    ]  # fmt: skip
    assert not circles, "import circles:\n" + "\n".join(described)


def test_the_circle_check_can_fail(tmp_path: Path) -> None:
    """Guard against a vacuous check: a circle closed by a lazy import is found, one closed
    only under TYPE_CHECKING is not."""
    (tmp_path / "engine").mkdir()
    (tmp_path / "engine" / "__init__.py").write_text("")
    (tmp_path / "engine" / "a.py").write_text("from sparsesplat.engine import b\n")
    (tmp_path / "engine" / "b.py").write_text(
        "def later():\n    from sparsesplat.engine.a import x\n"
    )
    (tmp_path / "engine" / "c.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from . import d\n"
    )
    (tmp_path / "engine" / "d.py").write_text("from .c import y\n")
    graph = _import_graph(tmp_path, ("engine",))
    assert _import_circles(graph) == [["sparsesplat.engine.a", "sparsesplat.engine.b"]]


def _reachable(graph: dict[str, set[str]], start: str) -> set[str]:
    """Every module of ours that importing ``start`` can load: its imports, lazy ones
    included, and the packages above each (Python runs a package's ``__init__`` first)."""
    seen: set[str] = set()
    todo = [start]
    while todo:
        module = todo.pop()
        if module in seen or module not in graph:
            continue
        seen.add(module)
        parts = module.split(".")
        todo.extend(".".join(parts[:i]) for i in range(2, len(parts)))
        todo.extend(graph[module])
    return seen


def test_the_render_worker_does_not_load_the_training_package() -> None:
    """Serving renders needs the trained model (engine/model), not the trainer: a render
    worker that loaded engine/train would pay its imports and could not be shipped without
    it."""
    graph = _import_graph(REPO, PACKAGES)
    loaded = _reachable(graph, "sparsesplat.worker.render_server")
    assert "sparsesplat.engine.model" in loaded  # the walk reaches what it renders with
    training = sorted(m for m in loaded if m.startswith("sparsesplat.engine.train"))
    assert not training, f"the render worker can load {training}"
    # And the check sees the trainer where it is loaded.
    assert "sparsesplat.engine.train" in _reachable(graph, "sparsesplat.worker.job_runner")
