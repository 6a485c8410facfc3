"""Matches cached per upload: a content hash of the photos, masks and settings names a small
``.npz`` file in a folder the caller owns (a job's work folder, a scene cache)."""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from torch import Tensor

from sparsesplat.engine.match.deps import versions
from sparsesplat.engine.match.errors import MatchError
from sparsesplat.engine.match.matcher import match_images
from sparsesplat.engine.match.result import FORMAT_VERSION, MatchSet
from sparsesplat.engine.match.settings import MatchSettings

log = logging.getLogger(__name__)

CACHE_PREFIX = "matches-"
"""File names are ``matches-<hash>.npz``."""


def _array_bytes(value: np.ndarray | Tensor) -> tuple[str, bytes]:
    arr = value.detach().cpu().numpy() if isinstance(value, Tensor) else np.asarray(value)
    arr = np.ascontiguousarray(arr)
    return f"{arr.dtype.str}{arr.shape}", arr.tobytes()


def content_key(
    photos: Sequence[np.ndarray | Tensor],
    settings: MatchSettings,
    masks: Sequence[np.ndarray | None] | None = None,
) -> str:
    """SHA-256 (hex) over the photos' pixels (dtype and shape included, in order), the masks,
    the settings, the match file format and the versions of torch, kornia and the weight
    packages: equal keys mean the matcher would compute the same thing."""
    digest = hashlib.sha256()
    digest.update(f"format={FORMAT_VERSION};settings={settings.as_json()};".encode())
    digest.update(repr(sorted(versions().items())).encode())
    for i, photo in enumerate(photos):
        head, body = _array_bytes(photo)
        digest.update(f"photo{i}:{head}:".encode())
        digest.update(body)
        mask = None if masks is None else masks[i]
        if mask is not None:
            head, body = _array_bytes(np.asarray(mask, dtype=bool))
            digest.update(f"mask{i}:{head}:".encode())
            digest.update(body)
    return digest.hexdigest()


def cache_path(cache_dir: Path, key: str) -> Path:
    """Where the matches with ``key`` are stored in ``cache_dir``."""
    return Path(cache_dir) / f"{CACHE_PREFIX}{key[:40]}.npz"


def cached_match(
    photos: Sequence[np.ndarray | Tensor],
    settings: MatchSettings | None = None,
    cache_dir: Path | None = None,
    masks: Sequence[np.ndarray | None] | None = None,
) -> tuple[MatchSet, bool]:
    """:func:`match_images`, read from ``cache_dir`` when the same photos were matched with
    the same settings before, else computed and written there. Returns the set and whether it
    came from the cache. Without ``cache_dir`` it always computes. An unreadable cache file is
    recomputed and replaced (logged), never trusted."""
    settings = settings or MatchSettings()
    if cache_dir is None:
        return match_images(photos, settings, masks), False
    path = cache_path(cache_dir, content_key(photos, settings, masks))
    if path.is_file():
        try:
            found = MatchSet.load(path)
            if found.settings == settings and len(found.keypoints) == len(photos):
                return found, True
            log.warning("match cache %s holds other settings: recomputing", path.name)
        except MatchError as exc:
            log.warning("match cache unreadable, recomputing: %s", exc)
    result = match_images(photos, settings, masks)
    result.save(path)
    return result, False
