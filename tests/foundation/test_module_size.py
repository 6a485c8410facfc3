"""No Python module of the project grows past 600 lines: a module that long holds more than one
idea (docs/architecture.md, "small modules with one job")."""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
FOLDERS = ("api", "client", "server", "worker", "engine", "benchmarks", "scripts", "tests")
MAX_LINES = 600


def long_modules(root: Path, folders: tuple[str, ...], limit: int) -> dict[str, int]:
    """Line counts of the ``.py`` files under ``root/<folder>`` longer than ``limit`` lines."""
    found = {}
    for folder in folders:
        for path in sorted((root / folder).rglob("*.py")):
            lines = len(path.read_text(encoding="utf-8").splitlines())
            if lines > limit:
                found[str(path.relative_to(root))] = lines
    return found


def test_no_module_is_longer_than_600_lines() -> None:
    assert (REPO / "engine" / "train").is_dir()  # the walk reads the real tree
    assert long_modules(REPO, FOLDERS, MAX_LINES) == {}


def test_the_size_check_can_fail(tmp_path: Path) -> None:
    (tmp_path / "engine").mkdir()
    (tmp_path / "engine" / "short.py").write_text("x = 1\n" * MAX_LINES)
    (tmp_path / "engine" / "long.py").write_text("x = 1\n" * (MAX_LINES + 1))
    assert long_modules(tmp_path, ("engine",), MAX_LINES) == {"engine/long.py": MAX_LINES + 1}
