"""fetch-weights against a real HTTP server on loopback: checksum verified, failures named."""

from __future__ import annotations

import hashlib
import http.server
import socket
import threading
from collections.abc import Iterator
from functools import partial
from pathlib import Path

import pytest

from sparsesplat.client.fetch_weights import FetchError, WeightFile, fetch_one


@pytest.fixture
def mirror(tmp_path: Path) -> Iterator[tuple[str, Path]]:
    root = tmp_path / "mirror"
    root.mkdir()
    handler = partial(http.server.SimpleHTTPRequestHandler, directory=str(root))
    handler.log_message = lambda *a, **k: None  # type: ignore[attr-defined]
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}", root
    server.shutdown()


def _item(name: str, payload: bytes, prefix_only: bool = False) -> WeightFile:
    digest = hashlib.sha256(payload).hexdigest()
    return WeightFile(name, "unused", digest[:8] if prefix_only else digest, "test")


def test_download_verify_and_skip(mirror: tuple[str, Path], tmp_path: Path) -> None:
    url, root = mirror
    payload = b"weights" * 1000
    (root / "w.pth").write_bytes(payload)
    models = tmp_path / "models"
    assert fetch_one(_item("w.pth", payload), models, base_url=url) == "downloaded"
    assert (models / "w.pth").read_bytes() == payload
    assert fetch_one(_item("w.pth", payload, prefix_only=True), models, base_url=url) == "present"


def test_checksum_mismatch_keeps_nothing(mirror: tuple[str, Path], tmp_path: Path) -> None:
    url, root = mirror
    (root / "w.pth").write_bytes(b"tampered")
    models = tmp_path / "models"
    with pytest.raises(FetchError, match="checksum mismatch"):
        fetch_one(_item("w.pth", b"genuine"), models, base_url=url)
    assert list(models.iterdir()) == []


def test_missing_file_and_no_network_are_clear(mirror: tuple[str, Path], tmp_path: Path) -> None:
    url, _ = mirror
    with pytest.raises(FetchError, match="HTTP 404"):
        fetch_one(_item("absent.pth", b""), tmp_path, base_url=url)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        dead = f"http://127.0.0.1:{s.getsockname()[1]}"
    with pytest.raises(FetchError, match="No network"):
        fetch_one(_item("w.pth", b""), tmp_path, base_url=dead, timeout=2)
