"""Typed exceptions raised by the engine. Each message names the offending input and the problem."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from sparsesplat.api.scenes.errors import SceneFormatError


class EngineError(Exception):
    """Base class for every error the engine raises on purpose."""


class CameraError(EngineError, ValueError):
    """A camera is malformed: non-finite values, a non-rigid rotation, bad intrinsics."""


class SceneError(EngineError, ValueError):
    """A scene cannot be loaded: missing or unreadable files, inconsistent sizes, bad splits."""


class PriorError(EngineError, RuntimeError):
    """A depth prior could not be computed (missing model file, bad model description, ...)."""


class RasterError(EngineError, RuntimeError):
    """The rasterizer was given inputs it cannot render (wrong shapes, devices, dtypes)."""


class TrainingDiverged(EngineError, FloatingPointError):
    """Training produced non-finite values; the message names the step and the parameter group."""


class ConfigError(EngineError, ValueError):
    """A training configuration value is invalid (the message names the dotted field)."""


class ExportError(EngineError, ValueError):
    """Gaussians cannot be exported or a file cannot be read back: bad shapes, bad headers."""


@contextmanager
def reraise_as(kind: type[EngineError]) -> Iterator[None]:
    """Re-raise the shared scene readers' :class:`SceneFormatError` as the engine's ``kind``
    (same message); usable as ``with`` block or as a function decorator."""
    try:
        yield
    except SceneFormatError as exc:
        raise kind(str(exc)) from exc
