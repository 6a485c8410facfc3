"""DropGaussian dropout: schedule, draw, compensation, scatter.

Statistical claims use fixed seeds (``parametrize``); float32 values are compared with a float64
reference under the rule of ``tests/engine/numerics.py``.
"""

from __future__ import annotations

import math

import pytest
import torch

from sparsesplat.engine.train.config import ConfigError
from sparsesplat.engine.train.regularizers.dropout import (
    OPACITY_CEILING,
    DropoutSchedule,
    compensated_logits,
    draw_dropout,
)
from tests.engine.numerics import assert_float32_close, compare_float32


def test_schedule_is_linear_and_zero_outside_training() -> None:
    s = DropoutSchedule(max_rate=0.2)
    assert s.rate(0, 100) == 0.0
    assert s.rate(50, 100) == pytest.approx(0.1)
    assert s.rate(100, 100) == pytest.approx(0.2)
    assert s.rate(101, 100) == 0.0
    assert DropoutSchedule(0.2, progressive=False).rate(1, 100) == 0.2


@pytest.mark.parametrize("bad", [-0.1, 1.0, float("nan")])
def test_invalid_rates_raise_config_error(bad: float) -> None:
    with pytest.raises(ConfigError):
        DropoutSchedule(max_rate=bad)
    with pytest.raises(ConfigError):
        draw_dropout(10, bad, torch.Generator())
    with pytest.raises(ConfigError):
        compensated_logits(torch.zeros(3), bad)


def test_rate_zero_is_identity() -> None:
    x = torch.randn(50)
    drop = draw_dropout(50, 0.0, torch.Generator())
    assert bool(drop.keep.all())
    assert torch.equal(drop.opacity_logits(x), x)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("rate", [0.1, 0.3])
def test_expected_opacity_mass_is_kept(seed: int, rate: float) -> None:
    """Mean over draws of sum_i keep_i * o'_i equals sum_i o_i: |error| below 4 standard errors
    of the mean (variance of one draw: sum o_i^2 * r / (1 - r), opacities below the cap)."""
    g = torch.Generator().manual_seed(seed)
    n, draws = 2000, 200
    logits = torch.rand(n, generator=g) * 4.0 - 4.0  # opacities 0.02..0.5, all below the cap
    o = torch.sigmoid(logits.double())
    assert float(o.max()) < OPACITY_CEILING * (1 - rate)
    masses = []
    for _ in range(draws):
        drop = draw_dropout(n, rate, g)
        masses.append(float(torch.sigmoid(drop.opacity_logits(logits).double()).sum()))
    mean = sum(masses) / draws
    std_err = math.sqrt(float((o * o).sum()) * rate / (1 - rate) / draws)
    assert abs(mean - float(o.sum())) < 4 * std_err, (mean, float(o.sum()), std_err)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_keep_fraction_matches_rate(seed: int) -> None:
    """Binomial(n, 1 - r) kept count within 4 standard deviations."""
    n, rate = 20_000, 0.25
    drop = draw_dropout(n, rate, torch.Generator().manual_seed(seed))
    kept = int(drop.keep.sum())
    sd = math.sqrt(n * rate * (1 - rate))
    assert abs(kept - n * (1 - rate)) < 4 * sd


def test_same_generator_state_replays_the_draw(seed: int) -> None:
    a = draw_dropout(500, 0.3, torch.Generator().manual_seed(seed))
    b = draw_dropout(500, 0.3, torch.Generator().manual_seed(seed))
    assert torch.equal(a.keep, b.keep)


def _reference_logits(x: torch.Tensor, rate: float, ceiling: float) -> torch.Tensor:
    """float64: logit(min(sigmoid(x) / (1 - rate), ceiling))."""
    o = (torch.sigmoid(x.double()) / (1 - rate)).clamp(max=ceiling)
    return torch.log(o) - torch.log1p(-o)


@pytest.mark.parametrize("rate", [0.05, 0.5, 0.9])
def test_compensated_logits_match_float64(rate: float, seed: int) -> None:
    """Values over the whole logit range (far negative, near the cap, far above it) within the
    float32 rule of the float64 reference; torch float32's direct formula is the scale."""
    g = torch.Generator().manual_seed(seed)
    x = torch.cat([torch.randn(500, generator=g) * 6, torch.tensor([-80.0, -20.0, 0.0, 30.0])])
    got = compensated_logits(x, rate)
    ref = _reference_logits(x, rate, OPACITY_CEILING)
    o32 = (torch.sigmoid(x) / (1 - rate)).clamp(max=OPACITY_CEILING)
    torch32 = torch.log(o32) - torch.log1p(-o32)
    # Entries of logit(o) are sums of terms of size |log o| and |log(1 - o)|.
    o64 = (torch.sigmoid(x.double()) / (1 - rate)).clamp(max=OPACITY_CEILING)
    terms = torch.log(o64).abs() + torch.log1p(-o64).abs()
    assert_float32_close(got, ref, torch32, terms=terms, what=f"rate {rate}")
    # The rule has teeth here: one entry off by 1e-3 of its terms fails it.
    bad = got.clone()
    bad[7] += 1e-3 * float(terms[7])
    assert not compare_float32(bad, ref, torch32, terms=terms).passed


def test_capped_gradient_is_the_uncapped_derivative() -> None:
    """Straight-through at the cap: d logit'/dx = sigmoid'(x) / ((1 - r) c (1 - c)); finite
    gradients for every entry (also the far-negative and far-positive logits)."""
    rate = 0.5
    x = torch.tensor([-90.0, -3.0, -1.0, 3.0, 40.0], requires_grad=True)
    out = compensated_logits(x, rate)
    out.sum().backward()
    assert x.grad is not None and bool(torch.isfinite(x.grad).all())
    xd = x.detach().double()
    o = torch.sigmoid(xd) / (1 - rate)
    capped = o >= OPACITY_CEILING
    c = OPACITY_CEILING
    d_sig = torch.sigmoid(xd) * (1 - torch.sigmoid(xd))
    want_capped = d_sig / ((1 - rate) * c * (1 - c))
    # Uncapped: d/dx [log o - log(1 - o)] = (1 - sigmoid(x)) / (1 - o)... via o' / (o (1 - o)).
    want_free = d_sig / (1 - rate) / (o * (1 - o)).clamp_min(1e-300)
    want = torch.where(capped, want_capped, want_free)
    assert bool(capped[3:].all()) and not bool(capped[:3].any())
    torch.testing.assert_close(x.grad.double(), want, rtol=1e-5, atol=1e-30)


def test_select_and_scatter_round_trip(seed: int) -> None:
    g = torch.Generator().manual_seed(seed)
    drop = draw_dropout(300, 0.4, g)
    values = torch.randn(300, 2, generator=g)
    back = drop.scatter(drop.select(values), fill=-7.0)
    assert torch.equal(back[drop.keep], values[drop.keep])
    assert bool((back[~drop.keep] == -7.0).all())
    radii = torch.randint(1, 5, (int(drop.keep.sum()),), dtype=torch.int32, generator=g)
    full = drop.scatter(radii)
    assert full.dtype == torch.int32 and bool((full[~drop.keep] == 0).all())
    with pytest.raises(ConfigError):
        drop.select(torch.zeros(299))


def test_empty_model_and_everything_dropped() -> None:
    """No Gaussians, or a draw that drops all of them: empty kept tensors, no error."""
    empty = draw_dropout(0, 0.5, torch.Generator())
    assert empty.keep.shape == (0,) and empty.opacity_logits(torch.zeros(0)).shape == (0,)
    g = torch.Generator().manual_seed(3)
    # With rate 0.99 and 2 Gaussians, some seed drops both; find it deterministically.
    for _ in range(100):
        drop = draw_dropout(2, 0.99, g)
        if not bool(drop.keep.any()):
            break
    assert not bool(drop.keep.any())
    assert drop.opacity_logits(torch.zeros(2)).shape == (0,)
    assert drop.scatter(torch.zeros(0, 2)).shape == (2, 2)


@pytest.mark.parametrize("kind", ["neural", "sh"])
def test_colouring_only_the_kept_rows_matches_colouring_all(kind: str) -> None:
    """``colors(..., rows)``: the kept rows' colours and centre gradients as with every row
    coloured, and no gradient on the dropped rows."""
    from sparsesplat.engine.color.models import NeuralColor, SHColor
    from sparsesplat.engine.gaussians import Gaussians

    g = torch.Generator().manual_seed(3)
    n = 3000
    points = torch.rand(n, 3, generator=g) * 2 - 1
    model: NeuralColor | SHColor
    extra: dict[str, torch.Tensor] = {}
    if kind == "neural":
        model = NeuralColor.create(points, g, log2_table_size=14)
    else:
        model = SHColor(3, 1, 3)
        extra = model.init_per_gaussian(n, g)
        extra["sh_rest"] = torch.randn(n, 15, 3, generator=g) * 0.1
    gauss = Gaussians.from_points(points, 0.1, extra)
    center = torch.tensor([0.2, -0.1, -4.0])
    drop = draw_dropout(n, 0.3, g)
    keep = drop.keep
    up = torch.rand(int(keep.sum()), 3, generator=g)

    full = model.colors(gauss, center)
    (full[keep] * up).sum().backward()
    grad_full = gauss.means.grad.clone()
    gauss.means.grad = None
    part = model.colors(gauss, center, drop.index)
    (part * up).sum().backward()

    assert part.shape == (int(keep.sum()), 3)
    # Row-wise the same computation; only the matrix products' blocking may round differently.
    torch.testing.assert_close(part, full[keep].detach(), rtol=0, atol=1e-6)
    torch.testing.assert_close(gauss.means.grad, grad_full, rtol=1e-5, atol=1e-7)
    assert not bool(gauss.means.grad[~keep].any())
