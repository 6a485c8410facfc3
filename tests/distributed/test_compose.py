"""docker/compose.yaml matches the real commands and settings (no Docker engine runs here;
`make test` also validates the file against the Compose Specification's schema)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from sparsesplat.api.settings import ENV_PREFIX, QueueBackend, Settings, load_settings
from sparsesplat.client.cli import build_parser

REPO = Path(__file__).resolve().parents[2]
COMPOSE = REPO / "docker" / "compose.yaml"


@pytest.fixture(scope="module")
def compose() -> dict[str, Any]:
    return dict(yaml.safe_load(COMPOSE.read_text()))


def _environment(service: dict[str, Any]) -> dict[str, str]:
    env = service.get("environment", {})
    if isinstance(env, list):
        env = dict(item.split("=", 1) for item in env)
    # ${NAME:-default} as compose interpolates it with NAME unset
    return {k: re.sub(r"\$\{[A-Z_]+:-([^}]*)\}", r"\1", str(v)) for k, v in dict(env).items()}


def test_every_sparsesplat_variable_is_a_setting_and_validates(
    compose: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    fields = {ENV_PREFIX + name.upper() for name in Settings.model_fields}
    for name in ("server", "worker"):
        env = _environment(compose["services"][name])
        unknown = {k for k in env if k.startswith(ENV_PREFIX)} - fields
        assert not unknown, f"{name}: not settings: {sorted(unknown)}"
        with monkeypatch.context() as patch:
            for key, value in env.items():
                patch.setenv(key, value)
            settings = load_settings()  # read from the environment, as the containers do
        assert settings.queue == QueueBackend.celery
        assert str(settings.database_url).startswith("postgresql://")


def test_urls_name_the_compose_services_and_credentials(compose: dict[str, Any]) -> None:
    services = compose["services"]
    postgres = services["postgres"]["environment"]
    env = _environment(services["worker"])
    expected_db = (
        f"postgresql://{postgres['POSTGRES_USER']}:{postgres['POSTGRES_PASSWORD']}"
        f"@postgres:5432/{postgres['POSTGRES_DB']}"
    )
    assert env["SPARSESPLAT_DATABASE_URL"] == expected_db
    assert env["SPARSESPLAT_BROKER_URL"].startswith("redis://redis:6379/")
    assert _environment(services["server"])["SPARSESPLAT_HOST"] == "0.0.0.0"
    for name in ("server", "worker"):
        assert set(services[name]["depends_on"]) == {"redis", "postgres"}
        assert all(v in ("data:/data", "models:/models") for v in services[name]["volumes"])


def test_commands_are_real_cli_commands(compose: dict[str, Any]) -> None:
    for name in ("server", "worker"):
        command = compose["services"][name]["command"]
        assert command[0] == "sparsesplat", command
        argv = [str(a) for a in command[1:]]
        args = build_parser(argv).parse_args(argv)  # exits (fails) on an unknown option
        assert args.command == {"server": "serve", "worker": "worker"}[name]
    server = compose["services"]["server"]["command"]
    assert server[server.index("--workers") + 1] == "0", "training belongs to the workers"


def test_dockerfiles_install_the_distributed_extra() -> None:
    for name in ("Dockerfile.cpu", "Dockerfile.cuda"):
        text = (REPO / "docker" / name).read_text()
        assert re.search(r"pip install [^\n]*\.\[service,distributed\]", text), name
