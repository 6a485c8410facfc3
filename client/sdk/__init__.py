"""The SDK's clients, laid out like their models: a base that builds requests and reads
answers, the sync and async transports over it, and the resources side by side.

``Client`` and ``AsyncClient`` have the same methods (the async ones are coroutines); so do
their job handles (``JobHandle`` / ``AsyncJobHandle``) and model handles (``ModelHandle`` /
``AsyncModelHandle``). Everything that is not I/O — URLs, headers, retry decisions, decoding,
error mapping, the event stream's resume bookkeeping — lives once:

- ``_config``  where the service is, :class:`Timeouts`, :class:`RetryPolicy`;
- ``_base``    request descriptions, decoding, errors, retries, every API call (``_Base``);
- ``_events``  :class:`~sparsesplat.client.sdk._events.EventCursor`, shared by both
  ``events()``;
- ``_client``  :class:`Client` and :class:`AsyncClient` (httpx + WebSocket I/O);
- ``jobs``, ``models``  the handles, sync and async class side by side;
- ``live``     :class:`LiveView` / :class:`AsyncLiveView`, a model's live view (poses in,
  frames out over a WebSocket);
- ``_output``  files, frames, DataFrames written from answers.

Both clients accept an injectable httpx ``transport``, so tests and embedders can route
requests anywhere (e.g. ``httpx.ASGITransport`` to an in-process app); the event stream is a
WebSocket and needs a real server.
"""

from sparsesplat.api.names import ExportFormat
from sparsesplat.client.sdk._client import AsyncClient, Client
from sparsesplat.client.sdk._config import (
    API_KEY_ENV,
    DEFAULT_RETRY,
    DEFAULT_TIMEOUTS,
    DEFAULT_URL,
    URL_ENV,
    EventCallback,
    IdempotencyKey,
    RetryPolicy,
    Timeouts,
)
from sparsesplat.client.sdk.jobs import AsyncJobHandle, JobHandle
from sparsesplat.client.sdk.live import AsyncLiveView, LiveView
from sparsesplat.client.sdk.models import AsyncModelHandle, ModelHandle

__all__ = [
    "API_KEY_ENV",
    "DEFAULT_RETRY",
    "DEFAULT_TIMEOUTS",
    "DEFAULT_URL",
    "URL_ENV",
    "AsyncClient",
    "AsyncJobHandle",
    "AsyncLiveView",
    "AsyncModelHandle",
    "Client",
    "EventCallback",
    "ExportFormat",
    "IdempotencyKey",
    "JobHandle",
    "LiveView",
    "ModelHandle",
    "RetryPolicy",
    "Timeouts",
]
