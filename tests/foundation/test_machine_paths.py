"""No file of the project names a path that only exists on one developer's machine (a checkout
under a home folder, a scratch worktree): commands in the docs and the code must work from
any clone, with the shared data at ``../shared``."""

from __future__ import annotations

import os
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SUFFIXES = {".py", ".md", ".toml", ".cfg", ".ini", ".txt", ".yml", ".yaml", ".sh", ".js",
            ".html", ".css", ".json", ".cpp", ".h"}  # fmt: skip
NAMES = {"Makefile", "Dockerfile", "README", "run"}
SKIPPED = {"build", "dist", "node_modules", "bench-results", "runs", "__pycache__"}
# Built from parts so that this file does not match itself.
MACHINE_PATH = re.compile("(?<![\\w.])/(" + "|".join(["wo" + "rk", "ho" + "me", "Us" + "ers",
                                                      "ro" + "ot"]) + ")/\\w")  # fmt: skip


def _skipped(folder: str) -> bool:
    """Hidden folders (a virtual environment, git), builds and run outputs are not read."""
    return folder.startswith(".") or folder in SKIPPED or folder.endswith(".egg-info")


def machine_paths(root: Path) -> list[str]:
    """``file:line`` of each line under ``root`` that names an absolute path under a machine's
    work, home or root folder (hidden and build folders are not read)."""
    found = []
    for folder, dirs, files in os.walk(root):
        # Pruned in place, so that a virtual environment or a build is never walked.
        dirs[:] = sorted(d for d in dirs if not _skipped(d))
        for name in sorted(files):
            path = Path(folder) / name
            if path.suffix not in SUFFIXES and name not in NAMES:
                continue
            text = path.read_text(encoding="utf-8", errors="replace")
            for number, line in enumerate(text.splitlines(), 1):
                if MACHINE_PATH.search(line):
                    found.append(f"{path.relative_to(root)}:{number}")
    return found


def test_no_file_names_a_machine_path() -> None:
    assert (REPO / "docs" / "experiments").is_dir()  # the walk reads the real tree
    assert machine_paths(REPO) == []


def test_the_machine_path_check_can_fail(tmp_path: Path) -> None:
    (tmp_path / "docs").mkdir()
    home = "/" + "ho" + "me"
    (tmp_path / "docs" / "log.md").write_text(f"ok: ../shared/data\nbad: {home}/dev/data\n")
    (tmp_path / "docs" / "fine.md").write_text("/mnt/shared and data/work/x are examples\n")
    (tmp_path / ".venv").mkdir()
    (tmp_path / ".venv" / "x.py").write_text(f"p = '{home}/dev'\n")
    assert machine_paths(tmp_path) == ["docs/log.md:2"]
