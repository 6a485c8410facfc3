"""Python SDK and command line for sparsesplat (httpx + the api schemas; never torch).

from sparsesplat.client import Client
with Client("http://127.0.0.1:8000") as c:
    print(c.health().status)
"""

from sparsesplat.client.errors import (
    APIError,
    AuthenticationError,
    ConnectionFailed,
    NotFound,
    ServerError,
    SparsesplatError,
    ValidationFailed,
)
from sparsesplat.client.sdk import AsyncClient, Client

__all__ = [
    "APIError",
    "AsyncClient",
    "AuthenticationError",
    "Client",
    "ConnectionFailed",
    "NotFound",
    "ServerError",
    "SparsesplatError",
    "ValidationFailed",
]
