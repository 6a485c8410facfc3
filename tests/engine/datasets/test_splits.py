"""The paper's splits, checked against the published indices."""

from __future__ import annotations

import pytest

from sparsesplat.engine.datasets.splits import blender_split, dtu_split, llff_split
from sparsesplat.engine.errors import SceneError

# Published 3-view LLFF train IDs (DNGaussian/RegNeRF, half-to-even rounding).
LLFF = {
    "fern": (20, [1, 10, 19]),
    "flower": (34, [1, 17, 33]),
    "fortress": (42, [1, 21, 41]),
    "horns": (62, [1, 30, 61]),
    "leaves": (26, [1, 12, 25]),
    "orchids": (25, [1, 12, 23]),
    "room": (41, [1, 20, 39]),
    "trex": (55, [1, 28, 54]),
}


@pytest.mark.parametrize("scene", sorted(LLFF))
def test_llff_split_matches_paper(scene: str) -> None:
    count, train = LLFF[scene]
    got_train, test = llff_split(count, 3)
    assert got_train == train
    assert test == list(range(0, count, 8))
    assert not set(got_train) & set(test)


def test_llff_more_views_and_too_few() -> None:
    train, _ = llff_split(20, 6)
    assert len(set(train)) == 6 and all(i % 8 for i in train)
    with pytest.raises(SceneError, match="at least 2"):
        llff_split(20, 1)
    with pytest.raises(SceneError, match="only 17"):
        llff_split(20, 18)


def test_dtu_and_blender_splits() -> None:
    train, test = dtu_split(49, 3)
    assert train == [25, 22, 28] and len(test) == 25 and 47 in test and 3 not in test
    assert dtu_split(49, 9)[0][-1] == 13
    train, test = blender_split(100, 200, 8)
    assert train == [26, 86, 2, 55, 75, 93, 16, 73]
    assert test == list(range(0, 200, 8)) and len(test) == 25


def test_dtu_background_mask_needs_a_dark_run_above() -> None:
    import torch

    from sparsesplat.engine.datasets.dtu import dtu_background_mask

    image = torch.full((120, 10, 3), 0.8)
    image[:100, :5] = 0.02  # a tall dark backdrop on the left
    image[105:115, 5:] = 0.02  # a short dark patch (object texture) on the right
    mask = dtu_background_mask(image)
    assert mask[:100, :5].all()
    assert not mask[100:, :5].any()
    assert not mask[105:115, 5:].any(), "short dark runs are not background"
