"""Matches cached per upload: hits, misses, and files that are not trusted. The matcher itself
is replaced by a counting stand-in, so this runs without the ``match`` extra."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sparsesplat.engine.match import MatchSettings, cache
from sparsesplat.engine.match.result import MatchSet


class CountingMatcher:
    """Stands in for ``match_images``: a fixed MatchSet built from the inputs, and a count."""

    def __init__(self) -> None:
        self.calls = 0

    def __call__(self, photos: Any, settings: MatchSettings, masks: Any = None) -> MatchSet:
        self.calls += 1
        kp = [np.array([[1.5, 2.5], [10.5, 20.5]], np.float32) for _ in photos]
        rows = {(0, 1): np.array([[0, 1], [1, 0]], np.int32)}
        return MatchSet(kp, rows, {(0, 1): np.array([0.9, 0.8], np.float32)},
                        [(p.shape[1], p.shape[0]) for p in photos], settings,
                        {"total": 1.0})  # fmt: skip


@pytest.fixture
def matcher(monkeypatch: pytest.MonkeyPatch) -> CountingMatcher:
    stub = CountingMatcher()
    monkeypatch.setattr(cache, "match_images", stub)
    return stub


def _photos(seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (24, 32, 3), dtype=np.uint8) for _ in range(2)]


def test_second_call_hits_and_returns_the_same_arrays(
    matcher: CountingMatcher, tmp_path: Path, seed: int
) -> None:
    photos = _photos(seed)
    first, hit1 = cache.cached_match(photos, MatchSettings(), tmp_path)
    second, hit2 = cache.cached_match([p.copy() for p in photos], MatchSettings(), tmp_path)
    assert (hit1, hit2, matcher.calls) == (False, True, 1)
    assert len(list(tmp_path.glob("matches-*.npz"))) == 1
    for a, b in zip(first.keypoints, second.keypoints, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(first.matches[(0, 1)], second.matches[(0, 1)])
    np.testing.assert_array_equal(first.scores[(0, 1)], second.scores[(0, 1)])
    assert second.settings == first.settings and second.sizes == first.sizes


def test_a_changed_pixel_setting_mask_or_order_misses(
    matcher: CountingMatcher, tmp_path: Path, seed: int
) -> None:
    photos = _photos(seed)
    cache.cached_match(photos, MatchSettings(), tmp_path)
    changed = [photos[0].copy(), photos[1]]
    changed[0][3, 4, 1] ^= 1
    mask = np.ones((24, 32), bool)
    mask[0, 0] = False
    for args in (
        (changed, MatchSettings(), None),
        (photos, MatchSettings(max_keypoints=1024), None),
        (photos, MatchSettings(), [mask, None]),
        (photos[::-1], MatchSettings(), None),
    ):
        _, hit = cache.cached_match(args[0], args[1], tmp_path, args[2])
        assert not hit
    assert matcher.calls == 5
    assert len(list(tmp_path.glob("matches-*.npz"))) == 5


def test_an_unreadable_cache_file_is_recomputed_and_replaced(
    matcher: CountingMatcher, tmp_path: Path, seed: int
) -> None:
    photos = _photos(seed)
    cache.cached_match(photos, MatchSettings(), tmp_path)
    (path,) = tmp_path.glob("matches-*.npz")
    path.write_bytes(b"not a zip file")
    _, hit = cache.cached_match(photos, MatchSettings(), tmp_path)
    assert not hit and matcher.calls == 2
    _, hit = cache.cached_match(photos, MatchSettings(), tmp_path)
    assert hit and matcher.calls == 2


def test_without_a_cache_folder_it_always_computes(matcher: CountingMatcher, seed: int) -> None:
    photos = _photos(seed)
    assert not cache.cached_match(photos, MatchSettings(), None)[1]
    assert not cache.cached_match(photos, MatchSettings(), None)[1]
    assert matcher.calls == 2


def test_the_key_covers_dtype_and_shape(seed: int) -> None:
    photos = _photos(seed)
    floats = [p.astype(np.float32) / 255 for p in photos]
    assert cache.content_key(photos, MatchSettings()) != cache.content_key(floats, MatchSettings())
    flat = [p.reshape(32, 24, 3) for p in photos]
    assert cache.content_key(photos, MatchSettings()) != cache.content_key(flat, MatchSettings())
