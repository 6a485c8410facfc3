"""The paper's train/test splits (DNGaussian, following RegNeRF / FreeNeRF / DietNeRF).

Pure Python: the even spacing reproduces ``np.linspace`` bit for bit (NumPy computes
``i * step`` and then sets the last value to the end point exactly), so the torch engine and
the torch-free SDK pick the same views.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, TypeVar

from sparsesplat.api.scenes.errors import SceneFormatError

LLFF_HOLDOUT = 8
"""LLFF (and instant-ngp): images with index i % 8 == 0 are test views."""

DTU_TRAIN_ORDER = (25, 22, 28, 40, 44, 48, 0, 8, 13)
"""DTU: the first n of these camera indices are the n training views."""

DTU_TEST = (1, 2, 9, 10, 11, 12, 14, 15, 23, 24, 26, 27, 29, 30, 31, 32, 33, 34, 35, 41, 42, 43,
            45, 46, 47)  # fmt: skip
"""DTU: the 25 test camera indices (the excluded views 3-7, 16-21, 36-39 are never used)."""

BLENDER_TRAIN_ORDER = (26, 86, 2, 55, 75, 93, 16, 73, 8)
"""Blender: training frame indices of transforms_train.json, DietNeRF/FreeNeRF order; the paper
uses the first 8 (the 9th, frame 8, is listed in the DNGaussian text and allows 9 views)."""

BLENDER_TEST_STRIDE = 8
"""Blender: every 8th frame of transforms_test.json is a test view (25 of 200)."""

TestViews = int | Literal["all"]
"""Held-out views to keep: ``"all"`` of the split's, a number (evenly spaced), or 0."""

T = TypeVar("T")


def linspace_round(count: int, views: int) -> list[int]:
    """``[round(k) for k in np.linspace(0, count - 1, views)]`` (Python's half-to-even round:
    LLFF horns gives 1, 30, 61, not 1, 31, 61)."""
    if views == 1:
        return [0]
    step = (count - 1) / (views - 1)
    values = [i * step for i in range(views)]
    values[-1] = float(count - 1)
    return [round(v) for v in values]


def evenly(pool: Sequence[T], views: int) -> list[T]:
    """``views`` items of ``pool`` evenly spaced from its first to its last."""
    return [pool[k] for k in linspace_round(len(pool), views)]


def check_view_count(views: int, available: int, source: str) -> None:
    """Raise SceneFormatError unless 2 <= views <= available."""
    if views < 2:
        raise SceneFormatError(f"{source}: at least 2 training views are needed, got views={views}")
    if views > available:
        raise SceneFormatError(
            f"{source}: views={views} training views requested, only {available} available"
        )


def llff_split(count: int, views: int, source: str = "scene") -> tuple[list[int], list[int]]:
    """(train, test) indices into a sorted list of ``count`` images, LLFF protocol: test =
    i % 8 == 0; train = ``views`` of the others, evenly spaced."""
    test = [i for i in range(count) if i % LLFF_HOLDOUT == 0]
    pool = [i for i in range(count) if i % LLFF_HOLDOUT != 0]
    check_view_count(views, len(pool), source)
    return evenly(pool, views), test


def dtu_split(count: int, views: int, source: str = "scene") -> tuple[list[int], list[int]]:
    """(train, test) camera indices for a DTU scan with ``count`` (49) images."""
    check_view_count(views, len(DTU_TRAIN_ORDER), source)
    needed = max(*DTU_TRAIN_ORDER, *DTU_TEST)
    if count <= needed:
        raise SceneFormatError(f"{source}: DTU split needs {needed + 1} images, found {count}")
    return list(DTU_TRAIN_ORDER[:views]), list(DTU_TEST)


def blender_split(
    train_count: int, test_count: int, views: int, source: str = "scene"
) -> tuple[list[int], list[int]]:
    """(train frame indices, test frame indices) for a NeRF-synthetic scene."""
    check_view_count(views, len(BLENDER_TRAIN_ORDER), source)
    train = list(BLENDER_TRAIN_ORDER[:views])
    if max(train) >= train_count:
        raise SceneFormatError(
            f"{source}: split needs train frame {max(train)}, only {train_count}"
        )
    return train, list(range(0, test_count, BLENDER_TEST_STRIDE))


def pick_tests(test: list[int], test_views: TestViews) -> list[int]:
    """The held-out indices to keep of ``test``: all, none, or ``test_views`` evenly spaced."""
    if test_views == "all":
        return test
    if test_views < 0:
        raise SceneFormatError(f"test_views must be 'all' or >= 0, got {test_views}")
    if test_views == 0 or not test:
        return []
    return evenly(test, min(test_views, len(test)))
