"""The errors of the artifact store, whatever backend holds the files."""

from __future__ import annotations


class ArtifactStoreError(RuntimeError):
    """The artifact store could not do what was asked (unreachable, a missing bucket, refused
    credentials); the message names the store and the cause."""


class ArtifactRefused(ArtifactStoreError):
    """The store refused the credentials (unknown key, wrong secret, access denied)."""


class ArtifactMissing(FileNotFoundError):
    """A file asked of the store is not there (never written, or deleted).

    A ``FileNotFoundError`` so that code reading local files handles both alike."""
