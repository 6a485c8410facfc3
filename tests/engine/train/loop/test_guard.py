"""The divergence guard's finite check (``all_finite``): the fast sum path must agree with the
exact element test on every kind of tensor, including the overflow case it falls back on."""

from __future__ import annotations

import pytest
import torch

from sparsesplat.engine.train.loop.guard import all_finite


def _exact(t: torch.Tensor) -> bool:
    return bool(torch.isfinite(t).all())


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
@pytest.mark.parametrize("where", [0, 1, 12_345, -1])
def test_one_non_finite_entry_is_found(bad: float, where: int) -> None:
    t = torch.randn(50_000, 2, generator=torch.Generator().manual_seed(0))
    t.view(-1)[where] = bad
    assert not all_finite(t)


def test_opposite_infinities_are_found() -> None:
    # +inf and -inf sum to NaN: still not finite.
    t = torch.zeros(1000)
    t[3], t[700] = float("inf"), -float("inf")
    assert not all_finite(t)


def test_finite_entries_whose_sum_overflows_are_finite() -> None:
    # Each entry is finite but the float32 sum overflows: the exact check decides.
    t = torch.full((16,), 3.0e38)
    assert not bool(torch.isfinite(t.sum()))
    assert all_finite(t)
    t[5] = float("nan")
    assert not all_finite(t)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_agrees_with_the_element_test_on_random_tensors(seed: int) -> None:
    g = torch.Generator().manual_seed(seed)
    for shape in [(0,), (1,), (7, 3), (4096, 2)]:
        t = torch.randn(shape, generator=g) * 1e3
        assert all_finite(t) == _exact(t)
        if t.numel():
            t.view(-1)[int(torch.randint(t.numel(), (1,), generator=g))] = float("nan")
            assert not _exact(t)
            assert not all_finite(t)
