"""The one interface a remote artifact backend implements: objects under string keys."""

from __future__ import annotations

from pathlib import Path
from typing import Protocol


class RemoteArtifacts(Protocol):
    """A flat store of objects under ``/``-separated keys (an S3 bucket and prefix).

    Every write is atomic: an object is visible whole or not at all (S3 shows an object,
    multipart ones included, only once it is complete). Errors are
    :class:`~sparsesplat.api.artifacts.errors.ArtifactStoreError` (or ``ArtifactMissing``).
    """

    @property
    def location(self) -> str:
        """Where the objects are, for messages (``s3://bucket/prefix``)."""
        ...

    def check(self) -> None:
        """Raise ``ArtifactStoreError`` naming the cause unless the store can be used now."""
        ...

    def put_file(self, key: str, path: Path) -> None:
        """Store the file ``path`` under ``key`` (replacing what was there)."""
        ...

    def get_file(self, key: str, path: Path) -> None:
        """Write the object ``key`` to ``path`` (complete, or not at all); ``ArtifactMissing``
        when there is none."""
        ...

    def exists(self, key: str) -> bool:
        """Whether an object ``key`` exists."""
        ...

    def sizes(self, prefix: str) -> dict[str, int]:
        """Every object under ``prefix`` (key → bytes)."""
        ...

    def modified(self, prefix: str) -> dict[str, float]:
        """Every object under ``prefix`` (key → when it was stored, Unix seconds)."""
        ...

    def delete_prefix(self, prefix: str) -> int:
        """Remove every object under ``prefix``; returns how many went."""
        ...
