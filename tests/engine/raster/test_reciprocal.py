"""The kernels' reciprocal must not depend on the CPU vendor's reciprocal estimate.

The backward divides by ``1 - alpha`` once per blended pair to undo the transmittance. It starts
from the hardware's estimate (AVX2 ``vrcpps``: relative error below 1.5 * 2^-12; AVX-512
``vrcp14ps``: below 2^-14), whose values differ between Intel and AMD CPUs, and refines it. Issue
59: Newton's second-order step left an error of -d^2 for an estimate off by d, always of one
sign, and on AMD CPUs (larger d) it compounded over long tile lists into gradients 4-6x torch's
float32 error. The refinement is third order, so for *any* estimate within the bound the result
is the rounded reciprocal up to ``u (1 + 2 d) + d^3``: this test feeds estimates at the bound,
of both signs, on both kernel variants, and checks the refinement the old kernels used fails it.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sparsesplat.engine.raster.build import load_extension

U = 2.0**-24
"""float32's unit roundoff."""
ESTIMATE_BOUND = 1.5 * 2.0**-12
"""The largest relative error of an x86 reciprocal estimate (vrcpps; vrcp14ps is below 2^-14)."""
ERROR_BOUND = U * (1 + 2 * ESTIMATE_BOUND) + ESTIMATE_BOUND**3
"""The refined reciprocal's relative error for any estimate within ESTIMATE_BOUND: the last
rounding (u), the rounding of e = 1 - x r and of e + e^2 carried through r (about 2 d u), and the
third-order step's remainder d^3."""


def _inputs(seed: int) -> np.ndarray:
    """x in [0.001, 1] (1 - alpha for alpha <= 0.999): random, plus the ends and powers of two."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.001, 1.0, 20000).astype(np.float32)
    edges = np.array([0.001, 1.0, 0.5, 0.25, 0.125, 0.999, np.nextafter(1, 0)], np.float32)
    return np.concatenate([x, edges])


def _estimates(x: np.ndarray, relative: float) -> np.ndarray:
    """float32 estimates of 1/x off by ``relative`` (kept inside the bound after rounding)."""
    return (1.0 / x.astype(np.float64) * (1.0 + relative)).astype(np.float32)


def _relative_errors(got: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Relative error of ``got`` against the exact 1/x (float64)."""
    exact = 1.0 / x.astype(np.float64)
    return (got.astype(np.float64) - exact) / exact


def _newton(x: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The refinement the kernels used before issue 59, r (2 - x r), in float32 with FMA."""
    t = (2.0 - x.astype(np.float64) * r.astype(np.float64)).astype(np.float32)  # one fused op
    return (r * t).astype(np.float32)


@pytest.mark.parametrize("relative", [ESTIMATE_BOUND * 0.999, -ESTIMATE_BOUND * 0.999, 0.0])
def test_reciprocal_is_rounded_whatever_the_estimate(raster_isa: str, relative: float,
                                                    seed: int) -> None:  # fmt: skip
    """Estimates at the vendors' bound, of either sign: every result within ERROR_BOUND of the
    exact reciprocal, and no drift of one sign (the mean error far below one roundoff)."""
    x = _inputs(seed)
    r = _estimates(x, relative)
    got = load_extension().reciprocal(torch.from_numpy(x), torch.from_numpy(r)).numpy()
    err = _relative_errors(got, x)
    worst = int(np.abs(err).argmax())
    assert np.abs(err).max() <= ERROR_BOUND, (
        f"{raster_isa}, estimate off by {relative:.3g}: 1/{x[worst]!r} has relative error "
        f"{err[worst]:.3g} (bound {ERROR_BOUND:.3g}, seed {seed})"
    )
    # Rounding to nearest is unbiased: over 20k inputs the mean is ~u / sqrt(20k) ~ 0.01 u.
    assert abs(err.mean()) <= 0.1 * U, f"{raster_isa}: mean error {err.mean():.3g} (seed {seed})"


def test_the_check_catches_a_second_order_refinement(seed: int) -> None:
    """The bound has teeth: Newton's step from an estimate at the bound misses it by -d^2."""
    x = _inputs(seed)
    err = _relative_errors(_newton(x, _estimates(x, ESTIMATE_BOUND * 0.999)), x)
    assert np.abs(err).max() > ERROR_BOUND
    assert err.mean() < -U, f"Newton's step should drift low: mean {err.mean():.3g}"


def test_every_variant_can_be_selected_and_restored() -> None:
    """set_variant switches the kernels in-process and says what was in use; unknown names and
    variants the CPU cannot run are refused by name."""
    ext = load_extension()
    before = ext.variant()
    assert "avx2" in ext.available_variants()
    assert ext.set_variant("avx2") == before
    assert ext.variant() == "avx2"
    assert ext.set_variant(before) == "avx2"
    with pytest.raises(RuntimeError, match="unknown rasterizer kernel variant 'neon'"):
        ext.set_variant("neon")
    if "avx512" not in ext.available_variants():
        with pytest.raises(RuntimeError, match="no AVX-512"):
            ext.set_variant("avx512")
    assert ext.variant() == before
