"""The export error type (kept here until the lead folds it into ``engine/errors.py``)."""

from __future__ import annotations

from sparsesplat.engine.errors import EngineError


class ExportError(EngineError, ValueError):
    """Gaussians cannot be exported or a file cannot be read back: bad shapes, bad headers."""
