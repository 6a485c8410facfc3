"""DTU background handling: the dark-pixel mask with its column run, the target edits, the
background-alpha loss and the near-black / near-white densification rule.

The mask is checked against a direct transcription of its rule (pixel by pixel, every row
above it); losses against float64 references with bounds from the computation.
"""

from __future__ import annotations

import math

import pytest
import torch

from sparsesplat.engine.errors import SceneError
from sparsesplat.engine.train.regularizers.dtu_background import (
    DtuBackgroundSettings,
    background_alpha_loss,
    background_mask,
    black_white_rule,
    blacken_background,
    fill_background_depth,
)
from tests.engine.numerics import UNIT_ROUNDOFF

U = UNIT_ROUNDOFF


def _rule(image: torch.Tensor, threshold: float, run: int) -> torch.Tensor:
    """The rule, written out: (r, c) is background iff rows max(0, r-run+1)..r are all dark."""
    _, h, w = image.shape
    dark = image.amax(dim=0) < threshold
    out = torch.zeros(h, w, dtype=torch.bool)
    for r in range(h):
        for c in range(w):
            out[r, c] = bool(dark[max(0, r - run + 1) : r + 1, c].all())
    return out


def _synthetic(seed: int, h: int = 120, w: int = 16) -> torch.Tensor:
    """Bright object on top, dark backdrop below, dark speckles in the object and bright
    speckles in the backdrop (they break the column runs below them)."""
    g = torch.Generator().manual_seed(seed)
    img = torch.rand(3, h, w, generator=g) * 0.5 + 0.4
    img[:, h // 3 :] = torch.rand(3, h - h // 3, w, generator=g) * (25 / 255)
    holes = torch.rand(h, w, generator=g) < 0.05
    img[:, holes] = 0.0
    sparks = torch.rand(h, w, generator=g) < 0.01
    img[:, sparks] = 0.5
    return img


def test_mask_matches_the_rule(seed: int) -> None:
    img = _synthetic(seed)
    s = DtuBackgroundSettings()
    assert torch.equal(background_mask(img, s), _rule(img, s.dark_threshold, s.run))


def test_mask_run_and_threshold_on_a_hand_made_column() -> None:
    """One column: 10 bright rows, then 60 dark rows. Dark rows 10..58 have a bright pixel
    within the 49 above; rows 59..69 do not. Exactly 30/255 is not dark (strict <)."""
    img = torch.zeros(3, 70, 1)
    img[:, :10] = 0.8
    m = background_mask(img)
    assert not bool(m[:59].any()) and bool(m[59:].all())
    img[0, 65, 0] = 30 / 255
    m = background_mask(img)
    assert not bool(m[65:].any()) and bool(m[59:65].all())
    # Top rows only need the rows that exist above them.
    top = torch.zeros(3, 5, 2)
    assert bool(background_mask(top).all())


def test_scan_specific_settings() -> None:
    assert DtuBackgroundSettings.for_scene("scan110").dark_threshold == pytest.approx(15 / 255)
    s110 = DtuBackgroundSettings.for_scene("dtu_scan110")
    assert not s110.black_rule and not s110.white_rule
    s21 = DtuBackgroundSettings.for_scene("scan21")
    assert s21.black_rule and not s21.white_rule
    assert DtuBackgroundSettings.for_scene("scan114").white_rule is False
    assert DtuBackgroundSettings.for_scene("scan24") == DtuBackgroundSettings()
    img = torch.full((3, 60, 2), 20 / 255)
    assert bool(background_mask(img).all())
    assert not bool(background_mask(img, DtuBackgroundSettings.for_scene("scan110")).any())


def test_blacken_background_edits_only_the_mask(seed: int) -> None:
    img = _synthetic(seed)
    m = background_mask(img)
    out = blacken_background(img, m)
    assert bool((out[:, m] == 0).all())
    assert torch.equal(out[:, ~m], img[:, ~m])
    assert blacken_background(out, background_mask(out)).equal(out)  # idempotent
    with pytest.raises(SceneError):
        blacken_background(img, m[:-1])


def test_fill_background_depth_values_and_gradient(seed: int) -> None:
    g = torch.Generator().manual_seed(seed)
    h, w = 40, 30
    mask = torch.rand(h, w, generator=g) < 0.4
    rendered = (torch.rand(1, h, w, generator=g) * 3 + 1).requires_grad_(True)
    prior = torch.rand(1, h, w, generator=g)
    r2, p2 = fill_background_depth(rendered, prior, mask)
    fg = ~mask
    for got, src in ((r2, rendered), (p2, prior)):
        ref = src.detach().double()[0][fg].mean()
        # A float32 mean of n positive terms: |error| <= n u max|term| (summation bound).
        bound = fg.sum() * U * float(src.detach().abs().max()) + U * float(ref)
        assert float((got.detach()[0][mask].double() - ref).abs().max()) <= float(bound)
        assert torch.equal(got.detach()[0][fg], src.detach()[0][fg])
    r2.sum().backward()
    assert rendered.grad is not None
    # Detached mean: gradient 1 on the foreground, 0 on the background.
    assert torch.equal(rendered.grad[0], fg.float())


def test_fill_background_depth_empty_and_full_masks() -> None:
    rendered = torch.rand(1, 8, 8, requires_grad=True)
    prior = torch.rand(1, 8, 8)
    r2, p2 = fill_background_depth(rendered, prior, torch.zeros(8, 8, dtype=torch.bool))
    assert r2 is rendered and p2 is prior
    r3, p3 = fill_background_depth(rendered, prior, torch.ones(8, 8, dtype=torch.bool))
    assert bool((r3 == 0).all()) and bool((p3 == 0).all())
    r3.sum().backward()
    assert rendered.grad is not None and bool((rendered.grad == 0).all())


def test_background_alpha_loss_against_float64(seed: int) -> None:
    g = torch.Generator().manual_seed(seed)
    alpha = torch.rand(1, 30, 20, generator=g).requires_grad_(True)
    mask = torch.rand(30, 20, generator=g) < 0.3
    loss = background_alpha_loss(alpha, mask)
    a64 = alpha.detach().double()[0][mask]
    ref = (a64 * a64).mean()
    n = int(mask.sum())
    # Squares (1 rounding each) summed (n - 1 roundings on partial sums <= the total) then
    # divided: |error| <= (n + 2) u * sum(a^2) / n.
    assert abs(float(loss.detach()) - float(ref)) <= (n + 2) * U * float((a64 * a64).sum()) / n
    loss.backward()
    assert alpha.grad is not None
    want = torch.where(mask, 2 * alpha.detach()[0].double() / n, torch.zeros(30, 20).double())
    err = (alpha.grad[0].double() - want).abs()
    assert float(err.max()) <= 4 * U * float(want.abs().max())


def test_background_alpha_loss_empty_and_full_masks() -> None:
    alpha = torch.rand(1, 6, 6, requires_grad=True)
    empty = background_alpha_loss(alpha, torch.zeros(6, 6, dtype=torch.bool))
    assert float(empty.detach()) == 0.0
    empty.backward()
    assert alpha.grad is not None and bool((alpha.grad == 0).all())
    full = background_alpha_loss(alpha.detach(), torch.ones(6, 6, dtype=torch.bool))
    assert math.isfinite(float(full))
    # All-background image end to end: mask everywhere, finite loss.
    black = torch.zeros(3, 60, 4)
    m = background_mask(black)
    assert bool(m.all()) and math.isfinite(float(background_alpha_loss(torch.rand(60, 4), m)))


def test_black_white_rule() -> None:
    colors = torch.tensor(
        [
            [0.05, 0.07, 0.02],  # near-black (max < 20/255 = 0.0784)
            [0.97, 0.95, 0.99],  # near-white (min > 240/255 = 0.941)
            [0.5, 0.5, 0.5],  # neither
            [20 / 255, 0.0, 0.0],  # max == 20/255 exactly: not black (strict)
        ]
    )
    adj = black_white_rule(colors, iteration=1000)
    assert adj.black.tolist() == [True, False, False, False]
    assert adj.white.tolist() == [False, True, False, False]
    torch.testing.assert_close(adj.grad_scale, torch.tensor([0.1, 0.5, 1.0, 1.0]))
    assert adj.reset.tolist() == [True, False, False, False]
    assert adj.reset_logit == pytest.approx(math.log(0.1 / 0.9))
    # The white reset fires only on multiples of 2001 (never on the reference's grid).
    assert black_white_rule(colors, iteration=4002).reset.tolist() == [True, True, False, False]
    off = black_white_rule(colors, 1000, DtuBackgroundSettings.for_scene("scan110"))
    assert not bool(off.reset.any()) and bool((off.grad_scale == 1).all())
    no_white = black_white_rule(colors, 4002, DtuBackgroundSettings.for_scene("scan21"))
    assert no_white.white.tolist() == [False] * 4 and no_white.reset.tolist()[0]
    empty = black_white_rule(torch.zeros(0, 3), 100)
    assert empty.grad_scale.shape == (0,)
    with pytest.raises(SceneError):
        black_white_rule(torch.zeros(4, 4), 100)
