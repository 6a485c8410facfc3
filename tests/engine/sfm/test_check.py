"""The refusals of ``engine.sfm.check`` that need no reconstruction: what a set of photos that
cannot start is told, from the match counts alone."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from sparsesplat.engine.sfm.check import MATCHER_REACH, best_partner, result_problem
from sparsesplat.engine.sfm.reconstruct import MatchStats, PairStats

NAMES = ["a.png", "b.png", "c.png"]


def _stats(pairs: dict[tuple[int, int], int]) -> MatchStats:
    return MatchStats(
        keypoints=[500, 500, 500],
        pairs={p: PairStats(inliers=n, displacement_px=20.0) for p, n in pairs.items()},
    )


def test_without_a_starting_pair_every_photo_is_named_with_its_nearest() -> None:
    # mic's three paper views, 64-132 degrees apart: no pair reaches the threshold.
    stats = _stats({(0, 1): 4, (1, 2): 12})
    problem = result_problem(NAMES, stats, None, min_inliers=30)
    assert problem is not None
    assert problem.startswith("no two photos share enough features to start from")
    assert "at least 30 verified matches needed" in problem
    assert (
        "each photo's best: photo 1 (a.png): 4 with photo 2 (b.png); "
        "photo 2 (b.png): 12 with photo 3 (c.png); photo 3 (c.png): 12 with photo 2 (b.png)"
    ) in problem
    assert problem.endswith(MATCHER_REACH)


def test_a_pair_that_matches_without_parallax_is_told_to_step_sideways() -> None:
    problem = result_problem(NAMES, _stats({(0, 2): 80}), None, min_inliers=30)
    assert problem is not None and "photos 1 (a.png) and 3 (c.png) match (80 matches)" in problem
    assert "step sideways" in problem


def test_best_partner_takes_the_most_matches_and_the_first_on_a_tie() -> None:
    stats = _stats({(0, 1): 5, (0, 2): 9})
    assert [best_partner(stats, 3, i) for i in range(3)] == [2, 0, 0]
    assert best_partner(_stats({}), 3, 1) == 0


def test_only_a_photo_that_matches_no_other_is_checked_for_mirroring(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Two left-out photos that match each other as they are (mic's far pair) are out of
    reach, not mirrored: only the one that matches no photo is handed to the mirror check."""
    import sparsesplat.engine.sfm.estimate as estimate

    asked = []

    def spy(image_dir: Path, names: list[str], candidates: list[int], *rest: Any) -> dict:
        asked.append(candidates)
        return {}

    monkeypatch.setattr(estimate, "mirrored", spy)
    names = [f"{i}.png" for i in range(6)]
    stats = MatchStats(
        keypoints=[500] * 6,
        pairs={
            (0, 1): PairStats(200, 30.0), (1, 2): PairStats(150, 30.0),
            (3, 4): PairStats(88, 30.0), (0, 5): PairStats(12, 30.0),
        },
    )  # fmt: skip
    placed = SimpleNamespace(world_to_camera={0: None, 1: None, 2: None})
    reasons = {3: "far", 4: "far", 5: "alone"}
    estimate._refuse_mirrored(tmp_path, names, names, reasons, placed, stats, 30, 0)  # type: ignore[arg-type]
    assert asked == [[5]]
    asked.clear()
    estimate._refuse_mirrored(tmp_path, names, names, {3: "far", 4: "far"}, placed, stats, 30, 0)  # type: ignore[arg-type]
    assert asked == []
