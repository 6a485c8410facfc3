"""The paper's train/test splits, raising :class:`SceneError` (the rules themselves live in
:mod:`sparsesplat.api.scenes.splits`, shared with the SDK)."""

from __future__ import annotations

from sparsesplat.api.scenes import splits as _splits
from sparsesplat.engine.errors import SceneError, reraise_as

LLFF_HOLDOUT = _splits.LLFF_HOLDOUT
DTU_TRAIN_ORDER = _splits.DTU_TRAIN_ORDER
DTU_TEST = _splits.DTU_TEST
BLENDER_TRAIN_ORDER = _splits.BLENDER_TRAIN_ORDER
BLENDER_TEST_STRIDE = _splits.BLENDER_TEST_STRIDE

check_view_count = reraise_as(SceneError)(_splits.check_view_count)
llff_split = reraise_as(SceneError)(_splits.llff_split)
dtu_split = reraise_as(SceneError)(_splits.dtu_split)
blender_split = reraise_as(SceneError)(_splits.blender_split)
