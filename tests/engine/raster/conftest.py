"""The rasterizer kernel variant as a test parameter.

The native rasterizer has one kernel source compiled for three targets on x86 (AVX2, the
baseline every x86-64-v3 CPU runs, AVX-512, and the portable generic-vector kernels that are the
only ones on other CPUs, NEON on aarch64). All variants are the same build on every x86
machine, so a test run on an AVX-512 CPU can exercise the AVX2 kernels in-process exactly as an
AVX2-only CPU runs them (except for the CPU's own reciprocal estimate, which
``test_reciprocal.py`` covers for any vendor), and the portable kernels' numerics natively
(``test_arm64_emulated.py`` runs them compiled for aarch64). ``raster_isa`` runs a test once per
variant this CPU can execute; a variant it lacks is skipped, by name.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from sparsesplat.engine.raster.build import load_extension

ISAS = ("avx2", "avx512", "portable")
"""The kernel variants of the native rasterizer."""


@pytest.fixture(params=ISAS)
def raster_isa(request: pytest.FixtureRequest) -> Iterator[str]:
    """Select the kernel variant ``request.param`` for the test, then restore the previous."""
    ext = load_extension()
    name = str(request.param)
    if name not in ext.available_variants():
        pytest.skip(f"this CPU cannot run the {name} kernels")
    previous = ext.set_variant(name)
    try:
        yield name
    finally:
        ext.set_variant(previous)
