"""The import graph goes one way, and the light packages never load torch."""

from __future__ import annotations

import ast
import subprocess
import sys
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
# The engine may import api's pure-pydantic schemas, so one schema validates the files the
# engine reads (cameras.json, render cameras) and one name set means the render modes — and only
# those modules: settings, logging, job and store modules stay out of the engine.
ENGINE_MAY_IMPORT_FROM_API = {"sparsesplat.api.cameras", "sparsesplat.api.renders"}
# What an api module the engine imports may itself import: the standard library and pydantic.
LIGHT_SCHEMA_DEPENDENCIES = {"pydantic"}


def _imported_modules(path: Path) -> list[tuple[str, int]]:
    """Every absolute module ``path`` imports, with ``from X import y`` also giving ``X.y``
    (y may be a submodule); relative imports are returned with their level."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found: list[tuple[str, int]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(alias.name, 0) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            found.append((module, node.level))
            found += [(f"{module}.{alias.name}", node.level) for alias in node.names]
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


def _api_modules_imported_by_engine() -> dict[str, set[str]]:
    """``sparsesplat.api...`` module -> engine files importing it."""
    used: dict[str, set[str]] = {}
    for path in sorted((REPO / "engine").rglob("*.py")):
        for name, level in _imported_modules(path):
            parts = name.split(".")
            if level == 0 and parts[:2] == ["sparsesplat", "api"] and len(parts) > 2:
                # ``from sparsesplat.api.cameras import X`` also yields ``...cameras.X``.
                module = ".".join(parts[:3])
                used.setdefault(module, set()).add(str(path.relative_to(REPO)))
            elif level == 0 and name == "sparsesplat.api":
                used.setdefault(name, set()).add(str(path.relative_to(REPO)))
    return used


def test_engine_imports_only_the_pure_schema_modules_of_api() -> None:
    used = _api_modules_imported_by_engine()
    bad = {m: sorted(files) for m, files in used.items() if m not in ENGINE_MAY_IMPORT_FROM_API}
    assert not bad, f"engine may import only {sorted(ENGINE_MAY_IMPORT_FROM_API)} from api: {bad}"
    # The rule is live, not vacuous: the folder loader does validate through the api schema.
    assert "engine/datasets/folder.py" in used.get("sparsesplat.api.cameras", set())


@pytest.mark.parametrize("module", sorted(ENGINE_MAY_IMPORT_FROM_API))
def test_schema_modules_the_engine_imports_stay_light(module: str) -> None:
    """Statically: stdlib + pydantic (and the other light schema modules) only; at run time: no
    torch, no web stack, none of ours."""
    path = REPO / Path(*module.split(".")[1:]).with_suffix(".py")
    heavy = []
    for name, level in _imported_modules(path):
        top = name.split(".")[0]
        if level or top == "__future__" or top in sys.stdlib_module_names:
            continue
        light = any(name == m or name.startswith(m + ".") for m in ENGINE_MAY_IMPORT_FROM_API)
        if top not in LIGHT_SCHEMA_DEPENDENCIES and not light:
            heavy.append(name)
    assert not heavy, f"{module} imports beyond stdlib + pydantic: {sorted(set(heavy))}"
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
    """Guard against a vacuous rule: an engine-style import of api.settings is caught."""
    probe = tmp_path / "probe.py"
    probe.write_text("from sparsesplat.api.settings import Settings\nimport sparsesplat.api.logs\n")
    modules = {n for n, level in _imported_modules(probe) if not level}
    assert {"sparsesplat.api.settings", "sparsesplat.api.logs"} <= modules
    assert not ({"sparsesplat.api.settings", "sparsesplat.api.logs"} & ENGINE_MAY_IMPORT_FROM_API)


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
