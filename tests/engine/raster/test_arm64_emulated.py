"""The rasterizer's aarch64 (NEON) tile kernels against the float64 reference, under emulation.

The portable kernels are cross-compiled for aarch64 and run under qemu-user (see ``arm64.py``);
the float32-rule comparisons of ``test_cpu_vs_reference.py``, ``test_opacity_depth.py`` and
``test_reciprocal.py`` then run with every tile blended by them. They need Debian's
``g++-aarch64-linux-gnu`` and ``qemu-user``: without them the tests skip, saying so, unless
``SPARSESPLAT_REQUIRE_ARM64=1`` (``make test-arm64``), which makes a missing tool a failure and
adds the sweep over fixed seeds. One random seed of the saturated and long-list scenes runs
always.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

from sparsesplat.engine.raster import cpu_backend, rasterize
from sparsesplat.engine.raster.build import load_extension

# Modules, not their test functions: a test function imported by name would be collected here
# a second time, without the emulation.
from . import arm64, test_cpu_vs_reference, test_opacity_depth
from .helpers import assert_matches_reference, camera, random_gaussians
from .test_reciprocal import ERROR_BOUND, ESTIMATE_BOUND, U, _estimates, _inputs, _relative_errors

REQUIRE_ENV = "SPARSESPLAT_REQUIRE_ARM64"
"""Set to 1 to fail, not skip, when the cross compiler or qemu is missing."""
SWEEP_SEEDS = range(10)
"""Fixed seeds of the emulated sweep (the native sweep runs 50; each emulated render starts two
qemu processes). The sweep runs with ``SPARSESPLAT_REQUIRE_ARM64=1`` only (``make test-arm64``):
it is most of the module's time (8 of 12 minutes on a loaded 2-core machine), too much for
every ``make test``."""


def _required() -> bool:
    """Whether the emulated tests must run in full (``make test-arm64``)."""
    return os.environ.get(REQUIRE_ENV) == "1"


@pytest.fixture(scope="module")
def arm64_driver() -> Iterator[Path]:
    """The driver, cross-compiled once for this module."""
    missing = arm64.missing_tools()
    if missing:
        reason = (f"{', '.join(missing)} not found: install Debian's g++-aarch64-linux-gnu and "
                  "qemu-user to test the aarch64 kernels under emulation")  # fmt: skip
        if _required():
            pytest.fail(reason)
        pytest.skip(reason)
    path = arm64.driver_path()
    try:
        yield arm64.build_driver(path)
    finally:
        shutil.rmtree(path.parent, ignore_errors=True)


@pytest.fixture
def emulated(arm64_driver: Path, monkeypatch: pytest.MonkeyPatch) -> arm64.EmulatedRaster:
    """The CPU backend with its tiles blended by the emulated aarch64 kernels."""
    shim = arm64.EmulatedRaster(load_extension(), arm64_driver)
    monkeypatch.setattr(cpu_backend, "load_extension", lambda: shim)
    monkeypatch.setattr(cpu_backend, "load_extension_or_none", lambda: shim)
    return shim


def test_the_cpu_backend_runs_the_emulated_kernels(emulated: arm64.EmulatedRaster) -> None:
    """The patch takes: a render's tiles come from the driver (its counters are the
    kernels')."""
    gs = random_gaussians(50, 0)
    out = rasterize(*gs.tensors(), camera(33, 20), backend="cpu")
    assert emulated.runs == 1
    assert out.stats is not None and out.stats["pairs_blended"] > 0
    assert float(out.alpha.max()) > 0.1


@pytest.mark.parametrize("channels", [3, 1, 0, 9, 12])
def test_random_scenes_match_reference(channels: int, seed: int, emulated: object) -> None:
    """Outputs and all five gradients within the float32 rule, for channel counts that take
    each of the kernels' paths (compile-time 0 and 3, any; lane sums by tree and one by one)."""
    gs = random_gaussians(120, seed, channels=channels)
    cam = camera(37, 29, fx=45.0, fy=41.0, cx=17.3, cy=15.1)
    bg = torch.rand(channels, generator=torch.Generator().manual_seed(seed))
    assert_matches_reference(gs, cam, seed, f"aarch64 random scene C={channels}", background=bg)


def test_dense_scene_saturates_like_reference(seed: int, emulated: object) -> None:
    """Many opaque Gaussians: early termination decides most pixels."""
    test_cpu_vs_reference._check_saturated_scene(seed)


@pytest.mark.parametrize("opacity", [0.012, 0.02])
def test_long_tile_lists_match_reference(opacity: float, seed: int, emulated: object) -> None:
    """Hundreds of faint Gaussians per pixel, with and without saturation."""
    test_cpu_vs_reference._check_long_lists(opacity, seed)


@pytest.mark.parametrize("case", ["long lists o=0.012", "long lists o=0.02", "saturated"])
def test_long_lists_and_saturation_over_fixed_seeds(case: str, emulated: object) -> None:
    """Early termination and float32 error compounding along long lists, over SWEEP_SEEDS."""
    if not _required():
        pytest.skip(f"the emulated sweep runs with {REQUIRE_ENV}=1 (make test-arm64)")
    failures = []
    for s in SWEEP_SEEDS:
        try:
            if case == "saturated":
                test_cpu_vs_reference._check_saturated_scene(s)
            else:
                test_cpu_vs_reference._check_long_lists(float(case.rsplit("=", 1)[1]), s)
        except AssertionError as e:
            failures.append(f"seed {s}: {str(e).splitlines()[0]}")
    assert not failures, f"{case} on aarch64: " + "\n".join(failures)


@pytest.mark.parametrize("channels", [0, 3])
def test_opacity_only_backward(channels: int, seed: int, emulated: object) -> None:
    """The geometry-free backward (the soft-depth pass's)."""
    test_cpu_vs_reference.test_opacity_only_backward_matches_reference(channels, seed)


def test_fused_soft_depth(seed: int, emulated: object) -> None:
    """The opacity-only depth gradient fused into the backward (v_depth_opacity)."""
    test_opacity_depth.test_fused_soft_depth_matches_two_renders_in_float64(seed % 3)


@pytest.mark.parametrize("relative", [ESTIMATE_BOUND * 0.999, -ESTIMATE_BOUND * 0.999, 0.0])
def test_reciprocal_is_rounded_whatever_the_estimate(
    relative: float, seed: int, emulated: arm64.EmulatedRaster
) -> None:
    """The refinement of a given estimate, as on x86 (the kernels' own estimate on aarch64 is a
    division, which the x86 test of the portable variant covers natively)."""
    x = _inputs(seed)
    got = emulated.reciprocal(x, _estimates(x, relative))
    err = _relative_errors(got, x)
    worst = int(np.abs(err).argmax())
    assert abs(err[worst]) <= ERROR_BOUND, f"1/{x[worst]!r}: relative error {err[worst]:.3g}"
    assert abs(err.mean()) <= 0.1 * U, f"mean error {err.mean():.3g} (seed {seed})"
