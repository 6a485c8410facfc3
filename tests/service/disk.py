"""Helpers for the full-disk tests: the fault rules file the service processes read
(``sparsesplat.api.faults``), partial files, renders of a model and the bytes on disk."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import httpx

from sparsesplat.api.disk import is_partial
from sparsesplat.api.faults import FAULTS_ENV

CAMERA_KEYS = ("convention", "pose", "matrix", "fx", "fy", "cx", "cy", "width", "height")


class Faults:
    """The rules file: :meth:`set` replaces the rules (the processes see it at once)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.set()

    def env(self) -> dict[str, str]:
        """The variable that points the service's processes at this file."""
        return {FAULTS_ENV: str(self.path)}

    def set(self, *rules: str) -> None:
        """Make ``rules`` the ones in force (none: the disk is healthy again)."""
        tmp = self.path.with_suffix(".new")
        tmp.write_text("".join(rule + "\n" for rule in rules))
        tmp.replace(self.path)
        time.sleep(0.05)  # a new mtime even on coarse clocks


def partial_files(data_dir: Path) -> list[Path]:
    """Every partial file (``*.tmp``, ``*.tmp.npz``) under the data folder."""
    return sorted(p for p in data_dir.rglob("*.tmp*") if is_partial(p))


def renders(url: str, model_id: str) -> bytes:
    """Render ``model_id`` at its first camera (asserts 200) and return the PNG."""
    cameras = httpx.get(f"{url}/v1/models/{model_id}", timeout=30).json()["cameras"]
    body = {"camera": {k: cameras[0][k] for k in CAMERA_KEYS}}
    answer = httpx.post(f"{url}/v1/models/{model_id}/render", json=body, timeout=120)
    assert answer.status_code == 200, answer.text
    return answer.content


def files_bytes(folder: Path) -> int:
    """Bytes of the regular files under ``folder``."""
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file() and not p.is_symlink())


def wait_for(check: Any, timeout: float, what: str, pause: float = 0.2) -> Any:
    """Poll ``check()`` until it returns something truthy (returned) or ``timeout`` passes."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = check()
        if value:
            return value
        time.sleep(pause)
    raise TimeoutError(f"{what}: not after {timeout} s")
