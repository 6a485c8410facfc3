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
    "engine": {"engine"},
}


def _our_imports(path: Path, package: str) -> set[str]:
    """Packages of ours that ``path`` imports (absolute ``sparsesplat.X`` or relative)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found: set[str] = set()
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative import stays inside the package
                found.add(package)
                continue
            names = [node.module or ""]
        for name in names:
            parts = name.split(".")
            if parts[0] == "sparsesplat" and len(parts) > 1 and parts[1] in PACKAGES:
                found.add(parts[1])
            elif parts[0] in PACKAGES:
                pytest.fail(
                    f"{path.relative_to(REPO)} imports bare '{name}'; use 'sparsesplat.{name}'"
                )
    return found


@pytest.mark.parametrize("package", PACKAGES)
def test_imports_follow_the_layering(package: str) -> None:
    violations = []
    for path in sorted((REPO / package).rglob("*.py")):
        bad = _our_imports(path, package) - ALLOWED[package]
        if bad:
            violations.append(f"{path.relative_to(REPO)} imports {sorted(bad)}")
    assert not violations, "layering violated:\n" + "\n".join(violations)


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
