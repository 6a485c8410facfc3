"""The fused native colour MLP (engine/color/cpu/mlp*.{h,cpp}) against its float64 reference.

The reference is :class:`~sparsesplat.engine.color.mlp.ColorMLP` (torch products) run in
float64 on the same float32 inputs; torch's float32 run of it is the scale of the float32 rule
(tests/engine/numerics.py). Points with a ReLU unit within float32's error of zero are left out:
float32 may switch that unit off where float64 does not, which changes the point's gradients by
a whole term.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from torch import Tensor

from sparsesplat.engine.color.mlp import ColorMLP
from sparsesplat.engine.color.native import NativeColorMLP
from tests.engine.numerics import (
    DECISION_SAFETY,
    FLOOR_ULPS,
    UNIT_ROUNDOFF,
    assert_float32_close,
    compare_float32,
    summed_terms,
)

SCALE, SHIFT = 1.002, 0.001
NAMES = ("colours", "code", "sh", "w0", "w1", "merged", "w_dir", "w2")
"""The outputs of :func:`_run`, in order: colours, then the gradients of each input."""


def _inputs(n: int, width: int, seed: int) -> list[Tensor]:
    """Grid code (n, width), direction code (n, 16) and the five weights, at the scales of a
    trained field (codes of order 0.1-1, weights ~ 1/sqrt(fan-in))."""
    g = torch.Generator().manual_seed(seed)
    code = torch.randn(n, width, generator=g) * 0.5
    sh = torch.randn(n, 16, generator=g) * 0.3
    shapes = [(64, width), (64, 64), (64, 64), (64, 16), (3, 64)]
    weights = [torch.randn(*s, generator=g) / s[1] ** 0.5 for s in shapes]
    return [code, sh, *weights]


def _run(fn: object, inputs: list[Tensor], upstream: Tensor, dtype: torch.dtype) -> list[Tensor]:
    """Colours and the gradients of every input for ``upstream``, in ``dtype``."""
    leaves = [x.to(dtype).clone().requires_grad_(True) for x in inputs]
    out = fn(*leaves, SCALE, SHIFT)  # type: ignore[operator]
    grads = torch.autograd.grad(out, leaves, upstream.to(dtype))
    return [out.detach(), *grads]


def _ambiguous(inputs: list[Tensor]) -> Tensor:
    """(n,) rows with a hidden unit whose float64 pre-activation is within float32's error of
    zero (the error measured by the magnitude of the terms it sums)."""
    code, sh, w0, w1, merged, w_dir, _ = (x.double() for x in inputs)
    ambiguous = torch.zeros(code.shape[0], dtype=torch.bool)

    def relu(pre: Tensor, terms: Tensor) -> Tensor:
        nonlocal ambiguous
        window = DECISION_SAFETY * FLOOR_ULPS * UNIT_ROUNDOFF * terms
        ambiguous |= (pre.abs() <= window).any(dim=-1)
        return torch.relu(pre)

    h1 = relu(code @ w0.t(), code.abs() @ w0.abs().t())
    h2 = relu(h1 @ w1.t(), h1 @ w1.abs().t())
    relu(sh @ w_dir.t() + h2 @ merged.t(), sh.abs() @ w_dir.abs().t() + h2 @ merged.abs().t())
    return ambiguous


def _check(got: list[Tensor], inputs: list[Tensor], upstream: Tensor, seed: int, msg: str) -> None:
    """Every output of the native run (made with ``upstream`` from :func:`_masked_upstream`)
    within the float32 rule of the float64 reference."""
    keep = ~_ambiguous(inputs)
    assert float(keep.double().mean()) > 0.8 or len(keep) < 10, f"too many ReLUs at 0, {msg}"
    assert not upstream[~keep].any(), f"the upstream gradient must skip ambiguous rows, {msg}"
    up = upstream
    want = _run(ColorMLP.apply, inputs, up, torch.float64)
    t32 = _run(ColorMLP.apply, inputs, up, torch.float32)
    # Weight gradients sum over every point's 3 colours, whose terms cancel.
    sizes = summed_terms(
        lambda u: _run(ColorMLP.apply, inputs, u, torch.float64)[3:], up, 3 * int(keep.sum()), seed
    )
    assert_float32_close(got[0][keep], want[0][keep], t32[0][keep], what=f"colours {msg}")
    for name, a, b, c in zip(NAMES[1:3], got[1:3], want[1:3], t32[1:3], strict=True):
        assert_float32_close(a, b, c, what=f"grad of {name} {msg}")
    for name, a, b, c, size in zip(NAMES[3:], got[3:], want[3:], t32[3:], sizes, strict=True):
        assert_float32_close(a, b, c, b.abs() + size, f"grad of {name} {msg}")


def _masked_upstream(inputs: list[Tensor], seed: int) -> Tensor:
    """A random upstream gradient, zero on the rows :func:`_check` leaves out."""
    g = torch.Generator().manual_seed(seed + 1)
    up = torch.randn(inputs[0].shape[0], 3, generator=g)
    return up * (~_ambiguous(inputs)).unsqueeze(-1)


@pytest.mark.parametrize(("n", "width"), [(1, 32), (77, 16), (2500, 32), (1100, 64)])
def test_native_mlp_matches_reference(n: int, width: int, seed: int) -> None:
    """Colours and every gradient within the float32 rule, for point counts that are and are
    not whole blocks (64) and chunks (1024), and each supported code width."""
    inputs = _inputs(n, width, seed)
    upstream = _masked_upstream(inputs, seed)
    got = _run(NativeColorMLP.apply, inputs, upstream, torch.float32)
    _check(got, inputs, upstream, seed, f"seed={seed} n={n} width={width}")


def test_the_check_catches_one_wrong_weight_gradient_entry(seed: int) -> None:
    """One weight-gradient entry off by 1e-4 of its terms' size, or one colour off by 1e-4 of
    itself, fails the rule: the comparison above can fail."""
    inputs = _inputs(600, 32, seed)
    upstream = _masked_upstream(inputs, seed)
    got = _run(NativeColorMLP.apply, inputs, upstream, torch.float32)
    want = _run(ColorMLP.apply, inputs, upstream, torch.float64)
    t32 = _run(ColorMLP.apply, inputs, upstream, torch.float32)
    bad = got[4].clone()
    bad[5, 7] += 1e-4 * float(want[4].abs().max())
    assert not compare_float32(bad, want[4], t32[4], want[4].abs()).passed
    colours = got[0].clone()
    colours[3, 1] *= 1 + 1e-4
    assert not compare_float32(colours, want[0], t32[0]).passed


def test_native_mlp_does_not_depend_on_the_thread_count(seed: int) -> None:
    """Bitwise the same colours and gradients with 1 and 2 threads: each point's products and
    each chunk's weight-gradient sums run in one fixed order whatever thread runs them."""
    inputs = _inputs(3000, 32, seed)
    upstream = torch.randn(3000, 3, generator=torch.Generator().manual_seed(seed))
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        two = _run(NativeColorMLP.apply, inputs, upstream, torch.float32)
        torch.set_num_threads(1)
        one = _run(NativeColorMLP.apply, inputs, upstream, torch.float32)
    finally:
        torch.set_num_threads(threads)
    for name, a, b in zip(NAMES, one, two, strict=True):
        assert torch.equal(a, b), f"{name} differs between 1 and 2 threads, seed={seed}"


def test_no_points_and_a_nan_row() -> None:
    """No points: empty colours and zero weight gradients. A NaN in one point's code makes that
    point's colour NaN (as torch's ReLU does, so a run's finiteness check sees it) and leaves
    the other points' colours exactly as without it."""
    empty = _inputs(0, 32, 0)
    got = _run(NativeColorMLP.apply, empty, torch.zeros(0, 3), torch.float32)
    assert got[0].shape == (0, 3) and got[1].shape == (0, 32)
    assert all(not g.any() for g in got[3:])
    inputs = _inputs(200, 32, 1)
    clean = _run(NativeColorMLP.apply, inputs, torch.ones(200, 3), torch.float32)[0]
    inputs[0][17, 5] = float("nan")
    dirty = _run(NativeColorMLP.apply, inputs, torch.ones(200, 3), torch.float32)[0]
    assert dirty[17].isnan().all()
    others = torch.arange(200) != 17
    assert torch.equal(dirty[others], clean[others])


_ISA_SCRIPT = """
import json, sys, torch
from sparsesplat.engine.color.build import load_extension
from sparsesplat.engine.color.native import NativeColorMLP
from tests.engine.color.test_color_mlp_native import _inputs, _masked_upstream, _run
seed = int(sys.argv[1])
inputs = _inputs(1500, 32, seed)
got = _run(NativeColorMLP.apply, inputs, _masked_upstream(inputs, seed), torch.float32)
torch.save(got, sys.argv[2])
print(json.dumps({"variant": load_extension().variant()}))
"""


def test_avx2_variant_matches_reference(seed: int, tmp_path: Path) -> None:
    """The AVX2 baseline kernels (forced by env, as on a CPU without AVX-512) agree with the
    float64 reference under the float32 rule too."""
    env = dict(os.environ, SPARSESPLAT_HASHGRID_ISA="avx2")
    out = tmp_path / "got.pt"
    done = subprocess.run(
        [sys.executable, "-c", _ISA_SCRIPT, str(seed), str(out)],
        env=env,
        cwd=Path(__file__).resolve().parents[3],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr[-4000:]
    assert json.loads(done.stdout.strip().splitlines()[-1])["variant"] == "avx2"
    inputs = _inputs(1500, 32, seed)
    _check(torch.load(out), inputs, _masked_upstream(inputs, seed), seed, f"avx2 seed={seed}")
