"""The paper's train/test splits (DNGaussian, following RegNeRF / FreeNeRF / DietNeRF)."""

from __future__ import annotations

import numpy as np

from sparsesplat.engine.errors import SceneError

LLFF_HOLDOUT = 8
"""LLFF: images with index i % 8 == 0 are test views."""

DTU_TRAIN_ORDER = (25, 22, 28, 40, 44, 48, 0, 8, 13)
"""DTU: the first n of these camera indices are the n training views."""

DTU_TEST = (
    1,
    2,
    9,
    10,
    11,
    12,
    14,
    15,
    23,
    24,
    26,
    27,
    29,
    30,
    31,
    32,
    33,
    34,
    35,
    41,
    42,
    43,
    45,
    46,
    47,
)
"""DTU: the 25 test camera indices (the excluded views 3-7, 16-21, 36-39 are never used)."""

BLENDER_TRAIN_ORDER = (26, 86, 2, 55, 75, 93, 16, 73, 8)
"""Blender: training frame indices of transforms_train.json, DietNeRF/FreeNeRF order; the paper
uses the first 8 (the 9th, frame 8, is listed in the DNGaussian text and allows 9 views)."""

BLENDER_TEST_STRIDE = 8
"""Blender: every 8th frame of transforms_test.json is a test view (25 of 200)."""


def check_view_count(views: int, available: int, source: str) -> None:
    """Raise SceneError unless 2 <= views <= available."""
    if views < 2:
        raise SceneError(f"{source}: at least 2 training views are needed, got views={views}")
    if views > available:
        raise SceneError(
            f"{source}: views={views} training views requested, only {available} available"
        )


def llff_split(count: int, views: int, source: str = "scene") -> tuple[list[int], list[int]]:
    """(train, test) indices into a sorted list of ``count`` images, LLFF protocol: test =
    i % 8 == 0; train = pool[round(k)] for k in linspace(0, len(pool) - 1, views) with Python's
    half-to-even ``round`` (horns gives 1, 30, 61, not 1, 31, 61)."""
    test = [i for i in range(count) if i % LLFF_HOLDOUT == 0]
    pool = [i for i in range(count) if i % LLFF_HOLDOUT != 0]
    check_view_count(views, len(pool), source)
    picks = [round(float(k)) for k in np.linspace(0, len(pool) - 1, views)]
    return [pool[k] for k in picks], test


def dtu_split(count: int, views: int, source: str = "scene") -> tuple[list[int], list[int]]:
    """(train, test) camera indices for a DTU scan with ``count`` (49) images."""
    check_view_count(views, len(DTU_TRAIN_ORDER), source)
    needed = max(*DTU_TRAIN_ORDER, *DTU_TEST)
    if count <= needed:
        raise SceneError(f"{source}: DTU split needs {needed + 1} images, found {count}")
    return list(DTU_TRAIN_ORDER[:views]), list(DTU_TEST)


def blender_split(
    train_count: int, test_count: int, views: int, source: str = "scene"
) -> tuple[list[int], list[int]]:
    """(train frame indices, test frame indices) for a NeRF-synthetic scene."""
    check_view_count(views, len(BLENDER_TRAIN_ORDER), source)
    train = list(BLENDER_TRAIN_ORDER[:views])
    if max(train) >= train_count:
        raise SceneError(f"{source}: split needs train frame {max(train)}, only {train_count}")
    return train, list(range(0, test_count, BLENDER_TEST_STRIDE))
