"""Native fused photometric loss (L1 + lambda * (1 - SSIM)): value, gradient, dispatch.

Numbers follow the float32 rule of ``tests/engine/numerics.py``: the native kernel and torch's
float32 implementation (``photometric_loss`` with $SPARSESPLAT_PHOTOMETRIC=torch) are both
measured against the torch implementation run in float64 on the same float32 inputs, and the
native error stays within 4x of torch's pooled error plus a floor of a few dozen roundoffs of
each entry's terms (:func:`_gradient_terms`).
"""

from __future__ import annotations

import pytest
import torch
from torch.nn import functional as F

from sparsesplat.engine.losses import SSIM_C1, SSIM_C2, SSIMTarget, photometric_loss
from sparsesplat.engine.photometric import native
from tests.engine.numerics import assert_float32_close, compare_float32

LAMBDAS = (0.2, 1.0)
"""DNGaussian's weight of the D-SSIM term, and a heavier one."""


def _run(
    pred: torch.Tensor, target: torch.Tensor, lam: float, backend: str, cached: bool = True
) -> tuple[torch.Tensor, torch.Tensor]:
    """(loss, d loss / d pred) by ``backend``: "native" or "torch" on the float32 inputs, or
    "float64" (the torch implementation on the inputs converted exactly to float64). ``cached``:
    pass the target's statistics as the trainer does (an :class:`SSIMTarget`)."""
    dtype = torch.float64 if backend == "float64" else torch.float32
    env = "torch" if backend == "float64" else backend
    x = pred.detach().to(dtype).clone().requires_grad_(True)
    y = target.to(dtype)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(native.BACKEND_ENV, env)
        loss = photometric_loss(x, y, lam, SSIMTarget(y) if cached else None)
    (grad,) = torch.autograd.grad(loss, x)
    return loss.detach(), grad


def _blur64(maps: torch.Tensor) -> torch.Tensor:
    """The SSIM window's zero-padded blur of (C, H, W) maps in float64, by the 2D definition
    (11x11 outer product of the sigma-1.5 Gaussian)."""
    coords = torch.arange(11, dtype=torch.float64) - 5
    g = torch.exp(-(coords**2) / (2 * 1.5**2))
    g = g / g.sum()
    c = maps.shape[0]
    w = (g[:, None] * g[None, :]).expand(c, 1, 11, 11)
    return F.conv2d(maps.unsqueeze(0), w, padding=5, groups=c)[0]


def _gradient_terms(pred: torch.Tensor, target: torch.Tensor, lam: float) -> torch.Tensor:
    """Magnitude of the terms each gradient entry sums, in float64: the L1 term 1/N plus
    lambda/N * (B|a| + 2|x| B|b| + |y| B|c|), where a, b, c are the SSIM's partials with respect
    to the blurred maps m, P, Q, each bounded by the sum of its own terms' magnitudes. Near
    x = y the partials are ~1/C2 ~ 1e3 and cancel to ~0, so the gradient itself is no scale."""
    x, y = pred.double(), target.double()
    m, p, q = _blur64(x), _blur64(x * x), _blur64(x * y)
    my, yy = _blur64(y), _blur64(y * y)
    a1 = 2 * m * my + SSIM_C1
    a2 = 2 * (q - m * my) + SSIM_C2
    b1 = m * m + my * my + SSIM_C1
    b2 = (p - m * m) + (yy - my * my) + SSIM_C2
    s = a1 * a2 / (b1 * b2)
    d = (b1 * b2).abs()
    ta = 2 / d * (my.abs() * (a2.abs() + a1.abs()) + (m * s).abs() * (b2.abs() + b1.abs()))
    tb = (s / b2).abs()
    tc = 2 * a1.abs() / d
    n = x.numel()
    return (1 + lam * (_blur64(ta) + 2 * x.abs() * _blur64(tb) + y.abs() * _blur64(tc))) / n


def _assert_rule(pred: torch.Tensor, target: torch.Tensor, lam: float, msg: str,
                 cached: bool = True) -> None:  # fmt: skip
    """Native value and gradient within the float32 rule of the float64 reference."""
    got = _run(pred, target, lam, "native", cached)
    ref = _run(pred, target, lam, "float64", cached)
    t32 = _run(pred, target, lam, "torch", cached)
    # The value is a mean of O(1) terms: |x - y| <= 1 and lambda * (1 - S) with |S| <= 1.
    assert_float32_close(got[0].reshape(1), ref[0].reshape(1), t32[0].reshape(1), 1 + 2 * lam,
                         f"value, {msg}")  # fmt: skip
    terms = _gradient_terms(pred, target, lam)
    assert_float32_close(got[1], ref[1], t32[1], terms, f"gradient, {msg}")


def _pair(shape: tuple[int, ...], seed: int, noise: float = 0.2) -> tuple[torch.Tensor, ...]:
    """A target in [0, 1] and a prediction near it (clamped like a rendered image), float32."""
    gen = torch.Generator().manual_seed(seed)
    y = torch.rand(shape, generator=gen)
    x = (y + noise * torch.randn(shape, generator=gen)).clamp(0, 1)
    return x, y


@pytest.mark.parametrize("lam", LAMBDAS)
@pytest.mark.parametrize("shape", [(3, 37, 53), (1, 64, 29), (3, 20, 24)])
def test_random_images(shape: tuple[int, int, int], lam: float, seed: int) -> None:
    """Value and gradient on random images, with and without cached target statistics."""
    x, y = _pair(shape, seed)
    _assert_rule(x, y, lam, f"seed={seed} shape={shape} lambda={lam}")
    _assert_rule(x, y, lam, f"uncached, seed={seed} shape={shape}", cached=False)


def test_far_and_near_predictions(seed: int) -> None:
    """An unrelated prediction (SSIM ~ 0, large partials of both signs) and one within a few
    float32 steps of the target (the L1 sign flips pixel by pixel, the D-SSIM cancels)."""
    gen = torch.Generator().manual_seed(seed)
    y = torch.rand(3, 30, 40, generator=gen)
    _assert_rule(torch.rand(3, 30, 40, generator=gen), y, 0.2, f"unrelated, seed={seed}")
    near = (y + 1e-6 * torch.randn(3, 30, 40, generator=gen)).clamp(0, 1)
    _assert_rule(near, y, 0.2, f"near, seed={seed}")


@pytest.mark.parametrize(
    ("pred_value", "target_value"),
    [(0.0, 0.0), (1.0, 1.0), (0.0, 1.0), (1.0, 0.0), (0.5, 0.5), (0.3, 0.7)],
)
def test_constant_images(pred_value: float, target_value: float) -> None:
    """Zero variance away from the borders (the window's zero padding gives some at them);
    0 and 1 everywhere. Both zero: every partial is finite and the gradient exactly 0."""
    x = torch.full((3, 23, 31), pred_value)
    y = torch.full((3, 23, 31), target_value)
    msg = f"constant {pred_value} vs {target_value}"
    _assert_rule(x, y, 0.2, msg)
    if pred_value == target_value == 0.0:
        loss, grad = _run(x, y, 0.2, "native")
        assert float(loss) == 0.0 and not grad.any(), msg


@pytest.mark.parametrize("shape", [(3, 1, 1), (1, 11, 3), (3, 3, 11), (2, 1, 17), (1, 2, 2)])
def test_images_smaller_than_the_window(shape: tuple[int, int, int], seed: int) -> None:
    """Tiny images where the 11-tap window overhangs every pixel on one or both axes."""
    x, y = _pair(shape, seed)
    _assert_rule(x, y, 0.2, f"seed={seed} shape={shape}")


def test_large_image(seed: int) -> None:
    """640x480 RGB, the size of a DTU view in the trainer."""
    x, y = _pair((3, 480, 640), seed, noise=0.1)
    _assert_rule(x, y, 0.2, f"seed={seed}")


@pytest.mark.parametrize("which", ["value", "gradient", "drift"])
def test_the_check_catches_a_wrong_result(which: str, seed: int) -> None:
    """The value off by 1e-4 of itself, one gradient entry (the largest) off by 1e-3 of itself,
    or every gradient entry off by 1e-4: each fails the rule that the real result passes."""
    x, y = _pair((3, 37, 53), seed)
    got, ref, t32 = (_run(x, y, 0.2, b) for b in ("native", "float64", "torch"))
    if which == "value":
        args = (got[0].reshape(1), ref[0].reshape(1), t32[0].reshape(1), 1.4)
        spoiled = args[0] * (1 + 1e-4)
    else:
        args = (got[1], ref[1], t32[1], _gradient_terms(x, y, 0.2))
        spoiled = got[1].clone()
        if which == "gradient":
            spoiled.view(-1)[int(spoiled.abs().argmax())] *= 1 + 1e-3
        else:
            spoiled *= 1 + 1e-4
    assert compare_float32(*args).passed, f"seed={seed}"
    assert not compare_float32(spoiled, *args[1:]).passed, f"{which}, seed={seed}"


def test_thread_count_does_not_change_the_result(seed: int) -> None:
    """Each output is summed in one fixed order: 1 and 2 threads agree bitwise."""
    x, y = _pair((3, 41, 67), seed)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        two = _run(x, y, 0.2, "native")
        torch.set_num_threads(1)
        one = _run(x, y, 0.2, "native")
    finally:
        torch.set_num_threads(threads)
    assert torch.equal(one[0], two[0]) and torch.equal(one[1], two[1]), f"seed={seed}"


def test_upstream_scale_and_no_grad(monkeypatch: pytest.MonkeyPatch, seed: int) -> None:
    """The backward scales the saved gradient by the upstream scalar; without a gradient
    asked for, the value is the same."""
    monkeypatch.setenv(native.BACKEND_ENV, "native")
    x, y = _pair((3, 16, 21), seed)
    target = SSIMTarget(y)
    xr = x.clone().requires_grad_(True)
    loss = photometric_loss(xr, y, 0.2, target)
    (grad,) = torch.autograd.grad(loss, xr)
    xr2 = x.clone().requires_grad_(True)
    (scaled,) = torch.autograd.grad(2.5 * photometric_loss(xr2, y, 0.2, target), xr2)
    assert torch.equal(scaled, grad * 2.5)
    with torch.no_grad():
        assert torch.equal(photometric_loss(x, y, 0.2, target), loss.detach())


def test_backend_selection(monkeypatch: pytest.MonkeyPatch) -> None:
    """float32 CPU images go native by default; the environment forces torch; float64, a
    target that needs a gradient or mismatched shapes fall back; bad values are errors."""
    x, y = _pair((3, 8, 9), 0)
    monkeypatch.delenv(native.BACKEND_ENV, raising=False)
    assert native.uses_native(x, y)
    assert not native.uses_native(x.double(), y.double())
    assert not native.uses_native(x, y.clone().requires_grad_(True))
    assert not native.uses_native(x, y[:, :4])
    assert not native.uses_native(x[0], y[0])
    monkeypatch.setenv(native.BACKEND_ENV, "torch")
    assert not native.uses_native(x, y)
    monkeypatch.setenv(native.BACKEND_ENV, "gpu")
    with pytest.raises(ValueError, match=native.BACKEND_ENV):
        photometric_loss(x, y, 0.2)
    monkeypatch.setenv(native.BACKEND_ENV, "native")
    with pytest.raises(ValueError, match="float32"):
        photometric_loss(x.double(), y.double(), 0.2)
    # A target with a gradient still works (torch path under auto) and receives its gradient.
    monkeypatch.setenv(native.BACKEND_ENV, "auto")
    yr = y.clone().requires_grad_(True)
    photometric_loss(x, yr, 0.2).backward()
    assert yr.grad is not None and yr.grad.abs().sum() > 0


def test_kernel_rejects_bad_arguments() -> None:
    """Shape, dtype and window mistakes are errors that name the argument."""
    from sparsesplat.engine.photometric.build import load_extension

    ext = load_extension()
    x = torch.rand(3, 5, 6)
    w = torch.ones(11) / 11
    with pytest.raises(RuntimeError, match="target: expected shape"):
        ext.forward(x, x[:, :4].contiguous(), x, x, x, w, 0.2, SSIM_C1, SSIM_C2, True)
    with pytest.raises(RuntimeError, match="pred: expected float32"):
        ext.forward(x.double(), x, x, x, x, w, 0.2, SSIM_C1, SSIM_C2, True)
    with pytest.raises(RuntimeError, match="window: expected an odd number"):
        ext.forward(x, x, x, x, x, torch.ones(10) / 10, 0.2, SSIM_C1, SSIM_C2, True)
