"""Who is calling: an API key's id, or ``anonymous`` when the service runs without keys.

Keys come from the database (``sparsesplat keys create``) and from ``SPARSESPLAT_API_KEYS``.
With none configured, every caller is ``anonymous``, which the server allows only while it
listens on loopback (checked at start-up, :func:`check_exposure`).
"""

from __future__ import annotations

import ipaddress
import time

from sparsesplat.api.settings import Settings
from sparsesplat.api.store.keys import KeyStore, owner_for

ANONYMOUS = "anonymous"
"""Owner of every job when no API keys are configured."""
_KEYS_TTL_S = 2.0


class Unauthenticated(Exception):
    """Missing or unknown API key; the message says which."""


class InsecureExposure(RuntimeError):
    """The server would accept anonymous requests on a non-loopback address."""


def is_loopback(host: str) -> bool:
    """Whether ``host`` is a loopback address or ``localhost``."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_exposure(settings: Settings, keys: KeyStore) -> None:
    """Refuse to serve anonymously on a non-loopback address (raises InsecureExposure)."""
    if is_loopback(settings.host) or settings.api_keys or keys.any_configured():
        return
    raise InsecureExposure(
        f"refusing to listen on {settings.host} without API keys: anyone who can reach it could "
        "submit jobs. Create a key with 'sparsesplat keys create NAME' (or set "
        "SPARSESPLAT_API_KEYS), or listen on 127.0.0.1."
    )


class Authenticator:
    """Maps an ``Authorization`` header to an owner id."""

    def __init__(self, settings: Settings, keys: KeyStore) -> None:
        """Keys from ``settings.api_keys`` and the ``keys`` table."""
        self.keys = keys
        self._env = {
            k.get_secret_value(): owner_for(k.get_secret_value()) for k in settings.api_keys
        }
        self._enabled = bool(self._env)
        self._checked_at = 0.0

    def _auth_enabled(self) -> bool:
        if self._env:
            return True
        if time.monotonic() - self._checked_at > _KEYS_TTL_S:
            self._enabled = self.keys.any_configured()
            self._checked_at = time.monotonic()
        return self._enabled

    def owner(self, authorization: str | None) -> str:
        """The caller's owner id; raises Unauthenticated."""
        if not self._auth_enabled():
            return ANONYMOUS
        if not authorization:
            raise Unauthenticated("missing API key: send 'Authorization: Bearer <key>'")
        scheme, _, key = authorization.partition(" ")
        if scheme.lower() != "bearer" or not key.strip():
            raise Unauthenticated("the Authorization header must be 'Bearer <key>'")
        key = key.strip()
        if key in self._env:
            return self._env[key]
        key_id = self.keys.verify(key)
        if key_id is None:
            raise Unauthenticated("unknown or revoked API key")
        return key_id
