"""The export error type; defined with the other engine errors and re-exported here."""

from __future__ import annotations

from sparsesplat.engine.errors import ExportError

__all__ = ["ExportError"]
