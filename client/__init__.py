"""Python SDK and command line for sparsesplat (httpx + the api schemas; never torch).

::

    from sparsesplat.client import Client

    with Client("http://127.0.0.1:8000") as c:
        job = c.submit_folder("scenes/mic", {"iterations": 2000}, views=3)
        job.wait()
        job.model.render_to(job.model.cameras("test")[0], "view.png")

``AsyncClient`` has the same methods as coroutines. docs/sdk.md is the guide.
"""

from sparsesplat.api.cameras import PinholeCamera
from sparsesplat.api.jobs import Event, Job, JobSpec, JobState, ModelInfo, Record
from sparsesplat.client import cameras
from sparsesplat.client.cameras import Intrinsics
from sparsesplat.client.errors import (
    APIError,
    AuthenticationError,
    Conflict,
    ConnectionFailed,
    InvalidInput,
    JobFailed,
    MissingExtra,
    NotFound,
    RateLimited,
    ServerError,
    ServiceUnavailable,
    SparsesplatError,
    Timeout,
    ValidationFailed,
)
from sparsesplat.client.scenes import Upload, from_images, read_scene
from sparsesplat.client.sdk import (
    DEFAULT_RETRY,
    DEFAULT_TIMEOUTS,
    AsyncClient,
    AsyncJobHandle,
    AsyncLiveView,
    AsyncModelHandle,
    Client,
    JobHandle,
    LiveView,
    ModelHandle,
    RetryPolicy,
    Timeouts,
)

__all__ = [
    "DEFAULT_RETRY",
    "DEFAULT_TIMEOUTS",
    "APIError",
    "AsyncClient",
    "AsyncJobHandle",
    "AsyncLiveView",
    "AsyncModelHandle",
    "AuthenticationError",
    "Client",
    "Conflict",
    "ConnectionFailed",
    "Event",
    "Intrinsics",
    "InvalidInput",
    "Job",
    "JobFailed",
    "JobHandle",
    "JobSpec",
    "JobState",
    "LiveView",
    "MissingExtra",
    "ModelHandle",
    "ModelInfo",
    "NotFound",
    "PinholeCamera",
    "RateLimited",
    "Record",
    "RetryPolicy",
    "ServerError",
    "ServiceUnavailable",
    "SparsesplatError",
    "Timeout",
    "Timeouts",
    "Upload",
    "ValidationFailed",
    "cameras",
    "from_images",
    "read_scene",
]
