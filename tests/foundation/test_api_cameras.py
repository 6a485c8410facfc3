"""The uploaded cameras file rejects what cannot be a camera, naming the problem."""

from __future__ import annotations

import math
import random

import pytest
from pydantic import ValidationError

from sparsesplat.api.cameras import CamerasFile, Intrinsics

POSE = {"convention": "opencv", "pose": "camera_to_world"}
"""Required on the wire: no default convention or pose direction."""


def _rotation(seed: int) -> list[list[float]]:
    """A random proper rotation from a random unit quaternion."""
    rng = random.Random(seed)
    q = [rng.gauss(0, 1) for _ in range(4)]
    n = math.sqrt(sum(x * x for x in q))
    w, x, y, z = (v / n for v in q)
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def _frame(name: str, seed: int, **changes: object) -> dict:
    r = _rotation(seed)
    frame = {
        "image": name,
        "matrix": [r[0] + [0.1], r[1] + [0.2], r[2] + [3.0], [0.0, 0.0, 0.0, 1.0]],
        "fx": 500.0,
        "fy": 510.0,
        "cx": 320.0,
        "cy": 240.0,
    }
    frame.update(changes)
    return frame


def test_valid_file_parses() -> None:
    seed = random.randrange(1 << 30)
    data = {
        **POSE,
        "convention": "opengl",
        "frames": [_frame("a.png", seed), _frame("b.png", seed + 1)],
    }
    parsed = CamerasFile.model_validate(data)
    assert parsed.convention == "opengl" and len(parsed.frames) == 2, f"seed {seed}"


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        ({"matrix": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "orthonormal"),
        ({"matrix": [[float("nan"), 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "NaN"),
        ({"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, "4x4"),
        ({"fx": 0}, "fx"),
    ],
)
def test_bad_frames_are_named(change: dict, needle: str) -> None:
    data = {**POSE, "frames": [_frame("a.png", 1, **change), _frame("b.png", 2)]}
    with pytest.raises(ValidationError) as info:
        CamerasFile.model_validate(data)
    assert needle in str(info.value)


def test_needs_two_training_views_and_unique_names() -> None:
    with pytest.raises(ValidationError, match="at least 2 training views"):
        CamerasFile.model_validate(
            {**POSE, "frames": [_frame("a.png", 1), _frame("b.png", 2, split="test")]}
        )
    with pytest.raises(ValidationError, match=r"more than once: a\.png"):
        CamerasFile.model_validate({**POSE, "frames": [_frame("a.png", 1), _frame("a.png", 2)]})


def test_one_intrinsics_serves_the_sdk_helpers_and_a_photos_only_upload() -> None:
    # In order (the SDK's camera helpers) or by name (a photos-only upload), the same model.
    lens = Intrinsics(50, 50, 16, 12, 32, 24)
    assert lens == Intrinsics(fx=50, fy=50, cx=16, cy=12, width=32, height=24)
    assert lens.size == (32, 24) and lens.fields()["width"] == 32
    assert lens.scaled(0.5) == Intrinsics(25, 25, 8, 6, 16, 12)
    upload = Intrinsics.model_validate_json('{"fx": 300, "fy": 300, "cx": 160, "cy": 120}')
    assert upload.size is None
    assert upload.model_dump(exclude_none=True) == {"fx": 300, "fy": 300, "cx": 160, "cy": 120}
    with pytest.raises(ValueError, match="no image size"):
        upload.fields()
    with pytest.raises(TypeError, match="both in order and by name"):
        Intrinsics(50, 50, 16, 12, fx=40)
    # Validation keeps the wire models' messages (it goes through the same __init__).
    with pytest.raises(ValidationError, match="missing 'cy'"):
        Intrinsics.model_validate({"fx": 1, "fy": 1, "cx": 0})
    with pytest.raises(ValidationError, match="did you mean 'width'"):
        Intrinsics.model_validate({"fx": 1, "fy": 1, "cx": 0, "cy": 0, "widht": 3})
    with pytest.raises(ValidationError):
        Intrinsics(0, 1, 0, 0)
