"""The matching-size check of a learned placement (``engine/sfm/recheck.py``): which second
size, how far photos moved, and that a planted move fails it while a small one passes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sparsesplat.engine.sfm.attempts import ATTEMPTS
from sparsesplat.engine.sfm.recheck import (
    MAX_MOVE_DEG,
    move_problem,
    moves_deg,
    second_size,
    working_side,
)
from sparsesplat.engine.sfm.reconstruct import Observed, Reconstruction

NAMES = ["a.png", "b.png", "c.png", "d.png"]
LEARNED = next(a for a in ATTEMPTS if a.matcher is not None)


def _yaw(degrees: float) -> np.ndarray:
    a = math.radians(degrees)
    r = np.eye(4)
    r[0, 0], r[0, 2], r[2, 0], r[2, 2] = math.cos(a), math.sin(a), -math.sin(a), math.cos(a)
    return r


def _rec(poses: dict[int, np.ndarray]) -> Reconstruction:
    empty = np.zeros((0, 3))
    return Reconstruction(
        world_to_camera=poses, intrinsics=(500.0, 500.0, 200.0, 200.0), points=empty,
        colours=empty.astype(np.float32), point_views=[], reprojection_error_px=0.3,
        observations=Observed(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2))),
    )  # fmt: skip


def _orbit() -> dict[int, np.ndarray]:
    """Four cameras 25 degrees apart around the origin, 4 units away."""
    poses = {}
    for i in range(4):
        w2c = _yaw(25.0 * i)
        w2c[2, 3] = 4.0
        poses[i] = w2c
    return poses


@pytest.mark.parametrize(
    ("longer", "first", "second"),
    [(400, 800, 1024), (800, 800, 1024), (960, 960, 1024), (1024, 1024, 800), (4032, 1024, 800)],
)
def test_the_second_size_differs_from_the_first(longer: int, first: int, second: int) -> None:
    other, a, b = second_size(LEARNED, longer)
    assert (a, b) == (first, second)
    assert working_side(longer, other.match_min_side or 0, other.match_max_side or 0) == second
    assert not other.recheck and other.matcher == LEARNED.matcher


def test_a_photo_that_moves_past_the_bar_is_named_and_a_small_move_passes() -> None:
    full = _orbit()
    # The same solution in another frame (turned, shifted, scaled): nothing moved.
    frame = _yaw(40.0)
    frame[:3, 3] = [1.0, 2.0, 3.0]
    again = {i: w2c @ np.linalg.inv(frame) for i, w2c in full.items()}
    for w2c in again.values():
        w2c[:3, 3] *= 2.5
    moved = moves_deg(_rec(full), _rec(again))
    assert max(moved.values()) < 1e-6
    assert move_problem(NAMES, moved, 800, 1024) is None
    # Photo 3 turned by 3.2 degrees about its own axis (mic's photos 3-6 moved so): refused.
    again[2] = _yaw(3.2) @ again[2]
    moved = moves_deg(_rec(full), _rec(again))
    assert moved[2] > MAX_MOVE_DEG
    problem = move_problem(NAMES, moved, 800, 1024)
    assert problem is not None and problem.startswith("photo 3 (c.png) moved")
    assert "at 1024 px instead of 800 px" in problem
    # Turned by 1 degree (fox from a guessed focal length moved 0.97): accepted.
    again[2] = _yaw(-2.2) @ again[2]
    assert move_problem(NAMES, moves_deg(_rec(full), _rec(again)), 800, 1024) is None


def test_a_photo_not_placed_again_fails_the_check() -> None:
    full = _orbit()
    partial = {i: w2c for i, w2c in full.items() if i != 3}
    problem = move_problem(NAMES, moves_deg(_rec(full), _rec(partial)), 1024, 800)
    assert problem is not None and "photo 4 (d.png) could not be placed again" in problem
    nothing = move_problem(NAMES, moves_deg(_rec(full), None), 1024, 800)
    assert nothing is not None and "could not be placed again" in nothing
