"""One rule for every test that checks a float32 implementation against a float64 reference.

Why: float32 results of torch's CPU kernels (GEMM, exp, reductions) and of our native kernels
are not bit-identical across CPUs, instruction sets or thread counts. A test that asks two
float32 paths to agree to 1e-6 of the value tests rounding: it passes on the machine it was tuned
on, fails on the next one, and cannot tell a real bug from a different CPU. So no test compares
two float32 paths with each other. Both are compared with the same float64 reference (the same
computation on the same float32 inputs), and the implementation under test must be about as
accurate as torch's own float32 run of it.

**The rule.** ``e = got - ref`` is the error of the implementation under test, ``e32 = torch32 -
ref`` the error of torch's float32 run, ``u = 2^-24`` float32's unit roundoff and ``terms`` the
magnitude of the terms each entry is a sum of. Both must hold:

1. every entry: ``|e_i| <= FACTOR * ||e32||_2 + FLOOR_ULPS * u * terms_i``
2. whole tensor: ``||e||_2 <= FACTOR * ||e32||_2 + FLOOR_ULPS * u * ||terms||_2``

Why each part:

- Torch's error is *pooled* (its L2 norm over the tensor), never taken entry by entry: the error
  of one entry is one random draw, and asking each entry to be within 4x of torch's error on
  that same entry fails on ~15 % of the entries of two equally good implementations. The L2
  norm of many draws is stable (measured on this suite's cases, 300 seeds per projection case
  and 150 per raster scene: the native kernels need at most 1.7x torch's, so ``FACTOR`` 4
  leaves a 2.3x margin) and it grows with the conditioning: a near-singular covariance whose
  gradient float32 keeps to 3 digits in torch too gets a correspondingly wide bound. Where a
  case has only a few draws (one Gaussian, a few needles), the tests pool jittered copies.
- ``FACTOR`` lets the implementation round in another order or use another exp, but not be an
  order of magnitude worse than torch.
- ``FLOOR_ULPS`` covers torch being exact by luck (a single entry, an identity rotation): up to
  32 roundoffs of the terms of an entry always pass, the noise of a few dozen float32 operations.
- ``terms``, not ``|ref|``: an entry that is a sum of large terms cancelling to ~0 keeps only
  float32's absolute precision of the terms, so a bound relative to the entry fails on correct
  code. Per-Gaussian rows computed from that Gaussian alone (projected means, conics, their
  gradients) use the row's largest entry (the default); an image uses its largest value;
  gradients that sum over pixels or points get their terms measured (:func:`summed_terms`,
  ``raster/helpers.gradient_terms``): a 1e4-scale Gaussian's opacity gradient of -2.3 summed
  terms of 143 over the image.

A real bug (one term wrong by 1e-4 of its size is ~1700 roundoffs) breaks part 1 for that entry
whatever torch's error, unless torch's whole-tensor error is itself that large; a small
systematic drift of every entry breaks part 2. Each test module that uses the rule perturbs one
entry or one term and asserts that the rule fails.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

UNIT_ROUNDOFF = 2.0**-24
"""float32's unit roundoff (half the distance from 1.0 to the next float32)."""
FACTOR = 4.0
"""How much larger than torch float32's pooled error the tested implementation's may be."""
FLOOR_ULPS = 32.0
"""Errors up to this many roundoffs of an entry's terms pass whatever torch's own error."""
DECISION_SAFETY = 16.0
"""Decisions (a threshold, a ReLU, a floor) taken within this many times float32's error of
their input may go either way in float32: tests leave such entries out (see the users)."""


def row_terms(ref: Tensor) -> Tensor:
    """Default magnitude of the terms: the largest ``|ref|`` of each row (last dimension) for a
    table of per-item rows, ``|ref|`` itself for a vector."""
    ref = ref.detach().double().abs()
    if ref.dim() <= 1 or ref.numel() == 0:
        return ref
    return ref.amax(dim=-1, keepdim=True).expand_as(ref)


@dataclass(frozen=True)
class Float32Comparison:
    """The figures of one comparison under the module's rule."""

    what: str
    worst_excess: float
    """max over entries of ``|e_i| - FLOOR_ULPS u terms_i``, in units of torch's ``||e32||``
    (inf when torch's is 0 and an entry exceeds its floor); part 1 holds when <= FACTOR."""
    l2_excess: float
    """``(||e|| - FLOOR_ULPS u ||terms||) / ||e32||``, likewise; part 2 holds when <= FACTOR."""
    l2_err: float
    """``||e||`` of the tested implementation."""
    l2_err32: float
    """``||e32||`` of torch's float32 run."""
    worst_entry: tuple[int, ...]
    """Index of the entry with the largest excess."""
    factor: float = FACTOR

    @property
    def passed(self) -> bool:
        """Both parts of the rule hold."""
        return self.worst_excess <= self.factor and self.l2_excess <= self.factor

    def message(self) -> str:
        """What failed, with the numbers."""
        return (
            f"{self.what}: error vs float64 beyond the float32 rule (module tests/engine/numerics"
            f"): entry {list(self.worst_entry)} is {self.worst_excess:.3g}x torch float32's "
            f"pooled error above its floor, the L2 error {self.l2_excess:.3g}x (allowed "
            f"{self.factor:g}x; ||e|| {self.l2_err:.3g}, torch's {self.l2_err32:.3g})"
        )


def _ratio(excess: float, base: float) -> float:
    """``excess / base`` with a non-positive excess counting as 0 (within the floor)."""
    if excess <= 0:
        return 0.0
    return excess / base if base > 0 else math.inf


def compare_float32(
    got: Tensor,
    ref: Tensor,
    torch32: Tensor,
    terms: Tensor | float | None = None,
    what: str = "",
    factor: float = FACTOR,
    floor_ulps: float = FLOOR_ULPS,
) -> Float32Comparison:
    """Measure ``got`` against ``ref`` per the module rule, with ``torch32`` (torch's float32 run
    of the same computation) as the scale of float32 rounding.

    ``terms`` (a tensor broadcastable to ``ref``, or a number) is the magnitude of the terms each
    entry sums; :func:`row_terms` when omitted. Entries where the reference is not finite must
    hold exactly the reference's value; a non-finite ``got`` elsewhere fails.
    """
    if got.shape != ref.shape or torch32.shape != ref.shape:
        raise AssertionError(f"{what}: shapes {tuple(got.shape)}, {tuple(torch32.shape)} vs "
                             f"{tuple(ref.shape)}")  # fmt: skip
    r = ref.detach().double()
    a, b = got.detach().double(), torch32.detach().double()
    if terms is None:
        s = row_terms(r)
    elif isinstance(terms, Tensor):
        s = terms.detach().double().abs().expand_as(r)
    else:
        s = torch.full_like(r, abs(float(terms)))
    finite = torch.isfinite(r)
    bad = not torch.equal(a[~finite], r[~finite]) or not bool(torch.isfinite(a[finite]).all())
    if bad:
        return Float32Comparison(what, math.inf, math.inf, math.inf, math.nan, (), factor)
    a, b, r, s = a[finite], b[finite], r[finite], s[finite]
    if r.numel() == 0:
        return Float32Comparison(what, 0.0, 0.0, 0.0, 0.0, (), factor)
    err = (a - r).abs()
    # Torch overflowing where the reference does not says nothing about rounding: count it as 0.
    err32 = torch.nan_to_num((b - r).abs(), nan=0.0, posinf=0.0)
    l2, l2_32 = float(err.norm()), float(err32.norm())
    floor = floor_ulps * UNIT_ROUNDOFF
    excess = err - floor * s
    worst = int(excess.argmax())
    full_index = torch.nonzero(finite)[worst] if finite.dim() else torch.zeros(0, dtype=torch.long)
    return Float32Comparison(
        what,
        _ratio(float(excess[worst]), l2_32),
        _ratio(l2 - floor * float(s.norm()), l2_32),
        l2,
        l2_32,
        tuple(int(i) for i in full_index),
        factor,
    )


def assert_float32_close(*args: Any, **kwargs: Any) -> Float32Comparison:
    """Assert the module rule for one tensor; takes :func:`compare_float32`'s arguments and
    returns its figures."""
    result = compare_float32(*args, **kwargs)
    assert result.passed, result.message()
    return result


def summed_terms(
    backward: Callable[[Tensor], Sequence[Tensor]],
    upstream: Tensor,
    n_terms: float,
    seed: int,
    samples: int = 4,
) -> list[Tensor]:
    """Magnitude of the terms of gradients that sum ``c_p = upstream_p * d out_p / d theta`` over
    ``n_terms`` outputs (a weight's gradient over a batch of points, a Gaussian's over pixels).

    The terms cancel, so the gradient itself says nothing of their size. With random signs
    ``s_p`` on the upstream gradient, ``E[(sum s_p c_p)^2] = sum c_p^2``; ``samples`` float64
    backward passes (``backward(upstream)`` returns the gradients) estimate ``Q = sqrt(sum
    c_p^2)``, and ``sum |c_p| <= sqrt(n_terms) Q`` (Cauchy-Schwarz). Returns that bound per
    entry of each gradient."""
    gen = torch.Generator().manual_seed(seed)
    squares: list[Tensor] | None = None
    for _ in range(samples):
        signs = torch.randint(0, 2, upstream.shape, generator=gen).to(upstream.dtype) * 2 - 1
        grads = [g.detach().double() for g in backward(upstream * signs)]
        if squares is None:
            squares = [g.square() for g in grads]
        else:
            squares = [acc + g.square() for acc, g in zip(squares, grads, strict=True)]
    assert squares is not None, "samples must be positive"
    return [(acc / samples).sqrt() * math.sqrt(max(n_terms, 1.0)) for acc in squares]
