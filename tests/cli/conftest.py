"""Fixtures for the CLI tests: the real ``sparsesplat`` command in a subprocess, and one small
trained model shared by a module."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.cli.scenes import write_object_scene

REPO = Path(__file__).resolve().parents[2]

SMOKE = [
    "--iterations", "20", "--no-depth", "--seed", "1",
    "--set", "hash_log2_size=14", "--set", "init_points=300", "--set", "eval_lpips=false",
    "--set", "export=false",
]  # fmt: skip
"""Train options that keep a CLI run to a few seconds."""


def run_cli(
    *args: str, env: dict[str, str] | None = None, timeout: float = 900
) -> subprocess.CompletedProcess[str]:
    """``python -m sparsesplat ARGS`` from the repository root; stdout/stderr captured. The
    timeout is generous: a first run after an engine update rebuilds the native extensions."""
    full_env = {**os.environ, **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "sparsesplat", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=full_env,
    )


def strict_json(text: str) -> object:
    """json.loads that refuses NaN / Infinity (what other JSON parsers refuse)."""

    def refuse(name: str) -> object:
        raise ValueError(f"non-standard JSON constant {name}")

    return json.loads(text, parse_constant=refuse)


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, list[str]]:
    """An RGBA object scene (OpenGL camera-to-world), trained by the CLI with ``--json``:
    (scene folder, run folder, stdout lines)."""
    base = tmp_path_factory.mktemp("trained")
    scene = write_object_scene(base / "scene", size=32)
    out = base / "run"
    result = run_cli("train", str(scene), "--out", str(out), "--json", *SMOKE)
    assert result.returncode == 0, result.stderr[-3000:]
    return scene, out, result.stdout.splitlines()


SceneWriter = Callable[..., Path]
