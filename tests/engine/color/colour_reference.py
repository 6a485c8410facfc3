"""float64 references of the colour field's pieces, for the float32 rule (tests/engine/numerics).

A float32 implementation takes decisions on float32 values: the hash grid's cell (``floor(x *
scale + 0.5)``) and inside/outside test, a ReLU's sign. Near a decision boundary float64 may
decide otherwise and the derivative jumps (the grid's position gradient switches cell, a ReLU
unit switches off). So the references here take the grid's decisions from the float32 inputs,
exactly as both float32 implementations do, and compute everything else in float64; ReLU
decisions within float32's error of zero are reported so that tests leave those points out.
"""

from __future__ import annotations

import torch
from torch import Tensor

from sparsesplat.engine.color.hashgrid import HashGrid, vertex_rows, vertex_weights
from sparsesplat.engine.color.neural import NeuralColorField
from sparsesplat.engine.color.sh import sh_basis
from tests.engine.numerics import DECISION_SAFETY, FLOOR_ULPS, UNIT_ROUNDOFF


def grid_reference(grid: HashGrid, x32: Tensor, x64: Tensor, table: Tensor) -> Tensor:
    """The hash grid of ``forward_torch`` in float64: cells and the inside test from the float32
    points ``x32`` (``x * scale + 0.5`` rounded twice, as both implementations do), weights from
    the float64 points ``x64`` (differentiable), rows from the float64 ``table``."""
    with torch.no_grad():
        inside = ((x32 >= 0) & (x32 <= 1)).all(dim=-1, keepdim=True)
        x32 = torch.where(inside, x32, torch.zeros_like(x32))
        c = grid._level_tables(x32.device)
        base = torch.floor(x32[:, None, :] * c["scale"][None, :, None] + 0.5)  # float32 decision
    x64 = torch.where(inside, x64, torch.zeros_like(x64))
    scale64 = c["scale"].double()[None, :, None]
    frac = x64[:, None, :] * scale64 + 0.5 - base.double()
    # forward_torch's own weight formula (here in float64) and vertex rows (integer decisions).
    w = vertex_weights(frac, c["corners"])
    index = vertex_rows(base.long()[:, :, None, :] + c["corners"], c)
    rows = table[index.reshape(-1)].reshape(*index.shape, -1)
    out = (w.unsqueeze(-1) * rows).sum(dim=2).reshape(x64.shape[0], -1)
    return out * inside.double()


def _relu_checked(pre: Tensor, terms: Tensor, ambiguous: Tensor) -> Tensor:
    """ReLU, marking in ``ambiguous`` the rows with a unit within float32's error of zero."""
    window = DECISION_SAFETY * FLOOR_ULPS * UNIT_ROUNDOFF * terms
    ambiguous |= (pre.detach().abs() <= window).any(dim=-1)
    return torch.relu(pre)


def field_reference(
    field: NeuralColorField,
    params: dict[str, Tensor],
    means: Tensor,
    camera_center: Tensor,
    means64: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """The colour field layer by layer in float64 with ``params`` (float64 copies of
    ``field.named_parameters()``, differentiable) at the float32 centres ``means``: the grid's
    decisions use their float32 grid input (computed as ``NeuralColorField._encode`` does), the
    values ``means64`` (their float64 copy, e.g. a leaf for the centres' gradient). The view
    direction's bands above ``field.view_degree`` are zero, as in the field.
    Returns (colours (N, 3) float64, ambiguous (N,) bool: a ReLU within float32's error of 0)."""
    m64 = means.double() if means64 is None else means64
    with torch.no_grad():
        x32 = (means.detach() - field.center) / (2 * field.bound) + 0.5
    x64 = (m64 - field.center.double()) / (2 * field.bound.double()) + 0.5
    code = grid_reference(field.grid, x32, x64, params["grid.embeddings"])
    ambiguous = torch.zeros(means.shape[0], dtype=torch.bool)

    def layer(x: Tensor, name: str) -> tuple[Tensor, Tensor]:
        w = params[name]
        return x @ w.t(), x.detach().abs() @ w.detach().abs().t()

    h, t = layer(code, "sigma_mlp.0.weight")
    h, t = layer(_relu_checked(h, t, ambiguous), "sigma_mlp.2.weight")
    geo, _ = layer(_relu_checked(h, t, ambiguous), "sigma_mlp.4.weight")
    dirs = torch.nn.functional.normalize(m64 - camera_center.double(), dim=-1)
    sh = sh_basis(dirs, 3)
    sh[:, (field.view_degree + 1) ** 2 :] = 0.0  # the bands the field does not see
    pre, t = layer(torch.cat([sh, geo[:, 1:]], dim=-1), "color_mlp.0.weight")
    out, _ = layer(_relu_checked(pre, t, ambiguous), "color_mlp.2.weight")
    return torch.sigmoid(out) * 1.002 - 0.001, ambiguous
