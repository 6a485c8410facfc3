"""Settings come from SPARSESPLAT_* variables, with typed validation and embedded defaults."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from sparsesplat.api.settings import Device, QueueBackend, Settings, load_settings


def test_defaults_are_the_embedded_setup(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.chdir(tmp_path)  # no stray .env
    for key in list(__import__("os").environ):
        if key.startswith("SPARSESPLAT_"):
            monkeypatch.delenv(key)
    s = load_settings()
    assert s.host == "127.0.0.1"
    assert s.queue is QueueBackend.local
    assert s.device is Device.cpu
    assert s.database_url == f"sqlite:///{Path('sparsesplat-data') / 'sparsesplat.db'}"
    assert not s.auth_enabled


def test_environment_overrides(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("SPARSESPLAT_PORT", "9123")
    monkeypatch.setenv("SPARSESPLAT_DATA_DIR", str(tmp_path / "d"))
    monkeypatch.setenv("SPARSESPLAT_QUEUE", "celery")
    monkeypatch.setenv("SPARSESPLAT_API_KEYS", '["k1", "k2"]')
    s = Settings()
    assert s.port == 9123
    assert s.queue is QueueBackend.celery
    assert s.database_url == f"sqlite:///{tmp_path / 'd' / 'sparsesplat.db'}"
    assert [k.get_secret_value() for k in s.api_keys] == ["k1", "k2"]
    assert "k1" not in repr(s)  # secrets never print


@pytest.mark.parametrize(
    ("key", "value"),
    [("SPARSESPLAT_PORT", "0"), ("SPARSESPLAT_QUEUE", "rabbit"), ("SPARSESPLAT_DEVICE", "tpu")],
)
def test_bad_values_name_the_field(monkeypatch: pytest.MonkeyPatch, key: str, value: str) -> None:
    monkeypatch.setenv(key, value)
    with pytest.raises(ValidationError) as info:
        Settings()
    assert key.removeprefix("SPARSESPLAT_").lower() in str(info.value)
