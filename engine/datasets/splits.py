"""The paper's train/test splits, raising :class:`SceneError` (the rules themselves live in
:mod:`sparsesplat.api.scenes.splits`, shared with the SDK)."""

from __future__ import annotations

from sparsesplat.api.scenes import splits as _splits
from sparsesplat.api.scenes.splits import (
    BLENDER_TEST_STRIDE,
    BLENDER_TRAIN_ORDER,
    DTU_TEST,
    DTU_TRAIN_ORDER,
    LLFF_HOLDOUT,
)
from sparsesplat.engine.errors import SceneError, reraise_as

check_view_count = reraise_as(SceneError)(_splits.check_view_count)
llff_split = reraise_as(SceneError)(_splits.llff_split)
dtu_split = reraise_as(SceneError)(_splits.dtu_split)
blender_split = reraise_as(SceneError)(_splits.blender_split)

__all__ = [
    "BLENDER_TEST_STRIDE",
    "BLENDER_TRAIN_ORDER",
    "DTU_TEST",
    "DTU_TRAIN_ORDER",
    "LLFF_HOLDOUT",
    "blender_split",
    "check_view_count",
    "dtu_split",
    "llff_split",
]
