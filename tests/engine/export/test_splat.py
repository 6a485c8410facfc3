"""The .splat writer: 32-byte records, field encodings, importance order, bad rows dropped."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
import torch

from sparsesplat.engine.export import ExportError, export_splat, read_splat
from sparsesplat.engine.export.sh_eval import C0
from tests.engine.export.conftest import random_gaussians


def test_record_layout_by_hand(tmp_path: Path) -> None:
    """Decode one record with struct, independently of the writer's numpy dtype."""
    sh = torch.zeros(1, 4, 3)
    sh[0, 0] = torch.tensor([0.5, -0.5, 10.0]) / C0  # rgb 1.0, 0.0, clipped to 1.0
    path = tmp_path / "one.splat"
    n = export_splat(
        path,
        means=torch.tensor([[1.0, -2.0, 3.5]]),
        log_scales=torch.log(torch.tensor([[0.1, 0.2, 0.4]])),
        quats=torch.tensor([[2.0, 0.0, 0.0, 0.0]]),  # not unit: the writer normalises
        opacity_logits=torch.tensor([0.0]),  # sigmoid -> 0.5
        sh=sh,
    )
    data = path.read_bytes()
    assert n == 1 and len(data) == 32
    fields = struct.unpack("<3f3f4B4B", data)
    assert fields[0:3] == (1.0, -2.0, 3.5)
    assert fields[3:6] == pytest.approx((0.1, 0.2, 0.4), rel=1e-6)
    assert fields[6:10] == (255, 0, 255, 128)  # alpha round(0.5*255)=128
    assert fields[10:14] == (255, 128, 128, 128)  # w=1 -> 1*128+128 clipped to 255


def test_sorted_by_volume_times_opacity_and_decodes(tmp_path: Path, seed: int) -> None:
    g = random_gaussians(200, 2, seed)
    path = tmp_path / "s.splat"
    assert export_splat(path, **g) == 200
    assert path.stat().st_size == 200 * 32
    back = read_splat(path)
    importance = torch.exp(g["log_scales"]).prod(1) * torch.sigmoid(g["opacity_logits"])
    order = torch.argsort(importance, descending=True)
    # alpha is quantised to 1/255, so check the order through the exact positions
    assert torch.equal(back["means"], g["means"][order]), f"seed {seed}"
    torch.testing.assert_close(back["scales"], torch.exp(g["log_scales"][order]))
    rgb = (g["sh"][order, 0] * C0 + 0.5).clamp(0, 1)
    assert (back["rgba"][:, :3] - rgb).abs().max() <= 0.5 / 255 + 1e-6, f"seed {seed}"
    unit = torch.nn.functional.normalize(g["quats"][order], dim=1)
    # same rotation up to quantisation (q and -q are the same rotation)
    dots = (back["quats"] * unit).sum(1).abs()
    assert dots.min() > 0.995, f"seed {seed}: worst quaternion agreement {dots.min():.4f}"


def test_non_finite_dropped_and_bad_shape(tmp_path: Path, seed: int) -> None:
    g = random_gaussians(10, 0, seed)
    g["log_scales"][4, 0] = float("nan")
    assert export_splat(tmp_path / "s.splat", **g) == 9
    assert (tmp_path / "s.splat").stat().st_size == 9 * 32
    g["means"] = torch.zeros(10, 2)
    with pytest.raises(ExportError, match="means"):
        export_splat(tmp_path / "b.splat", **g)


def test_reader_rejects_partial_records(tmp_path: Path) -> None:
    path = tmp_path / "odd.splat"
    path.write_bytes(b"\0" * 33)
    with pytest.raises(ExportError, match=r"odd\.splat"):
        read_splat(path)
