"""The one place pycolmap is imported: lazily, so the engine works without it."""

from __future__ import annotations

from types import ModuleType

from sparsesplat.engine.sfm.errors import MissingSfmDependency

PYCOLMAP_VERSION = "4.2.1"
"""The pinned pycolmap (COLMAP 3.x/4.x bindings with the binaries inside; see pyproject)."""


def require_pycolmap() -> ModuleType:
    """The pycolmap module with its logging quietened, or MissingSfmDependency saying what
    to install."""
    try:
        import pycolmap
    except ImportError as exc:
        raise MissingSfmDependency(
            "estimating cameras from photos needs pycolmap: pip install 'sparsesplat[sfm]' "
            f"(or pip install pycolmap=={PYCOLMAP_VERSION}); or give a cameras.json with poses"
        ) from exc
    # COLMAP logs every step at INFO on stderr; keep warnings and errors only.
    pycolmap.logging.minloglevel = 1
    return pycolmap
