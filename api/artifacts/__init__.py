"""Where job files are kept for good: the data folder alone (the embedded default), or an
S3-API bucket shared by every machine, the data folder then being each machine's working
copy (``SPARSESPLAT_ARTIFACTS=s3://bucket/prefix``).

``open_remote`` builds the remote backend the settings name (None: local files only);
:class:`~sparsesplat.api.storage.Storage` is the one interface the server and the workers use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from sparsesplat.api.artifacts.errors import ArtifactMissing, ArtifactRefused, ArtifactStoreError
from sparsesplat.api.artifacts.remote import RemoteArtifacts

if TYPE_CHECKING:
    from sparsesplat.api.settings import Settings

__all__ = [
    "ArtifactMissing",
    "ArtifactRefused",
    "ArtifactStoreError",
    "RemoteArtifacts",
    "open_remote",
]


def open_remote(settings: Settings) -> RemoteArtifacts | None:
    """The remote store ``settings.artifacts`` names, or None for local files only."""
    if not settings.artifacts:
        return None
    from sparsesplat.api.artifacts.s3 import S3Artifacts

    secret = settings.s3_secret_access_key
    return S3Artifacts(
        settings.artifacts,
        endpoint_url=settings.s3_endpoint_url,
        region=settings.s3_region,
        access_key_id=settings.s3_access_key_id,
        secret_access_key=secret.get_secret_value() if secret is not None else None,
    )
