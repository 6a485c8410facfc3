"""The console command: help, lazy subcommands, and a clear message when an extra is missing."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

_WITHOUT_TORCH = """
import sys
class BlockTorch:
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None
sys.meta_path.insert(0, BlockTorch())
from sparsesplat.client.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _run(*args: str, without_torch: bool = False) -> subprocess.CompletedProcess[str]:
    cmd = (
        [sys.executable, "-c", _WITHOUT_TORCH, *args]
        if without_torch
        else [sys.executable, "-m", "sparsesplat", *args]
    )
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120)


def test_help_lists_every_subcommand() -> None:
    result = _run("--help")
    assert result.returncode == 0
    for name in ("serve", "health", "scene", "train", "render", "fetch-weights"):
        assert name in result.stdout


def test_missing_engine_extra_is_named() -> None:
    result = _run("train", "some-scene", "--out", "x", without_torch=True)
    assert result.returncode == 3, result.stderr
    assert "pip install 'sparsesplat[engine]'" in result.stderr
    assert "torch" in result.stderr


def test_no_subcommand_prints_help() -> None:
    result = _run()
    assert result.returncode == 2
    assert "COMMAND" in result.stdout
