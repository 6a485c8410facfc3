"""gsplat (CUDA) backend against the float64 reference; skipped without a CUDA GPU.

Same float32 rule as the CPU kernel (``tests/engine/numerics.py``): gsplat's error against the
dense float64 reference stays within 4x of torch float32's own error on the scene. gsplat and
the CPU kernel are not compared with each other: two float32 implementations on two devices
need not round alike.
"""

from __future__ import annotations

import pytest

from .helpers import camera, compare_with_reference, random_gaussians

pytestmark = pytest.mark.cuda


@pytest.mark.parametrize("channels", [3, 0])
def test_gsplat_matches_reference(channels: int, seed: int) -> None:
    """Values and gradients within the float32 rule (same gsplat semantics as the reference)."""
    pytest.importorskip("gsplat")
    gs = random_gaussians(400, seed, channels=channels)
    cam = camera(96, 64, fx=80.0, fy=75.0, cx=45.0, cy=33.0)
    res = compare_with_reference(gs, cam, seed, f"gsplat C={channels}", backend="cuda")
    failed = [r.message() for r in res.comparisons if not r.passed]
    assert not failed, failed
    assert (res.out.radii.cpu() > 0).sum() > 0, f"nothing drawn (seed {seed})"
