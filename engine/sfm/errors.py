"""The typed failure of camera estimation: what went wrong, in words a photographer can act on."""

from __future__ import annotations

from sparsesplat.engine.errors import EngineError


class CameraEstimationError(EngineError, ValueError):
    """The photos' cameras could not be estimated reliably. The message names the photos
    involved (1-based, in the order given, with their file names) and what to change, e.g.
    "photos 2 (b.jpg) and 3 (c.jpg) share too few features (9 matches): take them closer
    together". A result that fails its checks raises this instead of returning a wrong frame."""


class MissingSfmDependency(EngineError, ImportError):
    """pycolmap (the ``sfm`` extra) is not installed."""
