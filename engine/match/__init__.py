"""Learned keypoints and matches for N photos, and the matched start built from them.

``match_images(photos, settings, masks)`` (or ``cached_match(..., cache_dir)``, keyed by a
content hash of the photos and settings) returns a :class:`MatchSet`; ``matched_start(matches,
cameras, photos)`` triangulates it with known cameras into coloured 3D points with initial
scales. The networks (XFeat, LighterGlue, DISK, LightGlue) come from the ``match`` extra and
are imported only when a matcher runs: this package imports with torch and numpy alone.
"""

from sparsesplat.engine.match.cache import cached_match, content_key
from sparsesplat.engine.match.errors import MatchError, MissingMatchDependency
from sparsesplat.engine.match.matcher import match_images
from sparsesplat.engine.match.result import MatchSet
from sparsesplat.engine.match.settings import METHODS, MatchSettings
from sparsesplat.engine.match.triangulate import (
    MatchedPoints,
    Observations,
    TriangulationSettings,
    matched_start,
)

__all__ = [
    "METHODS",
    "MatchError",
    "MatchSet",
    "MatchSettings",
    "MatchedPoints",
    "MissingMatchDependency",
    "Observations",
    "TriangulationSettings",
    "cached_match",
    "content_key",
    "match_images",
    "matched_start",
]
