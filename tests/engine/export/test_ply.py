"""The INRIA .ply writer and reader: layout, round trip, dropping bad rows, typed errors."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
import torch

from sparsesplat.engine.export import ExportError, export_ply, ply_property_names, read_ply
from tests.engine.export.conftest import random_gaussians

# The property list 3DGS writes for SH degree 3 (construct_list_of_attributes), spelled out.
INRIA_DEGREE3 = (
    ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    + [f"f_rest_{i}" for i in range(45)]
    + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
)


def _header(path: Path) -> list[str]:
    data = path.read_bytes()
    return data[: data.index(b"end_header")].decode("ascii").splitlines()


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_round_trip_is_exact(tmp_path: Path, degree: int, seed: int) -> None:
    g = random_gaussians(57, degree, seed)
    path = tmp_path / "scene.ply"
    assert export_ply(path, **g) == 57
    back = read_ply(path)
    assert set(back) == set(g)
    for key, value in g.items():
        assert torch.equal(back[key], value), f"{key} differs (seed {seed}, degree {degree})"


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_header_is_the_inria_property_list(tmp_path: Path, degree: int) -> None:
    g = random_gaussians(4, degree, 0)
    path = tmp_path / "scene.ply"
    export_ply(path, **g)
    n_rest = 3 * ((degree + 1) ** 2 - 1)
    expected = [p for p in INRIA_DEGREE3 if not p.startswith("f_rest_")]
    expected[9:9] = [f"f_rest_{i}" for i in range(n_rest)]
    assert ply_property_names(degree) == expected
    assert _header(path) == [
        "ply",
        "format binary_little_endian 1.0",
        "element vertex 4",
        *(f"property float {p}" for p in expected),
    ]
    assert path.stat().st_size == len("\n".join(_header(path))) + len("\nend_header\n") + (
        4 * 4 * len(expected)
    )


def test_f_rest_is_channel_major(tmp_path: Path) -> None:
    """f_rest_i runs over coefficients within a channel: all red, then green, then blue."""
    sh = torch.zeros(2, 16, 3)
    sh[:, 1, 0] = 1.0  # red, first higher-order coefficient -> f_rest_0
    sh[:, 15, 0] = 2.0  # red, last coefficient -> f_rest_14
    sh[:, 1, 1] = 3.0  # green, first -> f_rest_15
    sh[:, 2, 2] = 4.0  # blue, second -> f_rest_31
    g = random_gaussians(2, 3, 1) | {"sh": sh}
    path = tmp_path / "s.ply"
    export_ply(path, **g)
    data = path.read_bytes()
    body = data[data.index(b"end_header\n") + len(b"end_header\n") :]
    rows = np.frombuffer(body, dtype="<f4").reshape(2, 62)
    rest = rows[:, 9:54]
    expected = np.zeros(45, dtype=np.float32)
    expected[[0, 14, 15, 31]] = [1.0, 2.0, 3.0, 4.0]
    np.testing.assert_array_equal(rest[0], expected)
    np.testing.assert_array_equal(rows[:, 3:6], 0.0)  # normals are zeros


def test_non_finite_gaussians_are_dropped(
    tmp_path: Path, seed: int, caplog: pytest.LogCaptureFixture
) -> None:
    g = random_gaussians(20, 2, seed)
    g["means"][3, 1] = float("nan")
    g["sh"][7, 5, 2] = float("inf")
    g["opacity_logits"][11] = float("-inf")
    path = tmp_path / "s.ply"
    with caplog.at_level(logging.WARNING):
        assert export_ply(path, **g) == 17
    assert "dropped 3 of 20" in caplog.text
    keep = torch.ones(20, dtype=torch.bool)
    keep[[3, 7, 11]] = False
    back = read_ply(path)
    for key, value in g.items():
        assert torch.equal(back[key], value[keep]), f"{key} (seed {seed})"


def test_accepts_n_by_1_opacity_and_grad_tensors(tmp_path: Path) -> None:
    g = random_gaussians(5, 1, 2)
    g["opacity_logits"] = g["opacity_logits"][:, None].requires_grad_(True)
    export_ply(tmp_path / "s.ply", **g)
    assert torch.equal(read_ply(tmp_path / "s.ply")["opacity_logits"], g["opacity_logits"][:, 0])


@pytest.mark.parametrize(
    ("key", "shape", "needle"),
    [
        ("log_scales", (6, 2), "log_scales"),
        ("quats", (5, 4), "quats"),
        ("sh", (6, 5, 3), "sh"),
        ("sh", (6, 25, 3), "sh"),
        ("sh", (6, 4), "sh"),
    ],
)
def test_bad_shapes_raise_typed_error(
    tmp_path: Path, key: str, shape: tuple[int, ...], needle: str
) -> None:
    g = random_gaussians(6, 1, 3)
    g[key] = torch.zeros(shape)
    with pytest.raises(ExportError, match=needle) as err:
        export_ply(tmp_path / "bad.ply", **g)
    assert "bad.ply" in str(err.value)


def test_reader_rejects_non_ply_and_truncated(tmp_path: Path) -> None:
    bogus = tmp_path / "bogus.ply"
    bogus.write_bytes(b"hello")
    with pytest.raises(ExportError, match=r"bogus\.ply"):
        read_ply(bogus)
    path = tmp_path / "t.ply"
    export_ply(path, **random_gaussians(10, 0, 4))
    path.write_bytes(path.read_bytes()[:-8])
    with pytest.raises(ExportError, match="truncated"):
        read_ply(path)
    with pytest.raises(ExportError, match=r"missing\.ply"):
        read_ply(tmp_path / "missing.ply")


def test_reader_accepts_other_order_and_types(tmp_path: Path, seed: int) -> None:
    """Files from other tools may order properties differently or use doubles."""
    rng = np.random.default_rng(seed)
    names = ply_property_names(1)[::-1]
    values = rng.normal(size=(3, len(names)))
    header = "\n".join(
        ["ply", "format binary_little_endian 1.0", "comment from elsewhere", "element vertex 3"]
        + [f"property double {n}" for n in names]
        + ["end_header\n"]
    )
    path = tmp_path / "other.ply"
    path.write_bytes(header.encode() + values.astype("<f8").tobytes())
    back = read_ply(path)
    col = {n: values[:, i].astype(np.float32) for i, n in enumerate(names)}
    np.testing.assert_array_equal(back["means"][:, 2].numpy(), col["z"], err_msg=f"seed {seed}")
    np.testing.assert_array_equal(back["sh"][:, 2, 1].numpy(), col["f_rest_4"])
    np.testing.assert_array_equal(back["quats"][:, 3].numpy(), col["rot_3"])


def test_empty_model_round_trips(tmp_path: Path) -> None:
    """A run that pruned every Gaussian still exports valid (empty) files."""
    from sparsesplat.engine.export import export_splat, read_splat

    g = random_gaussians(0, 3, 0)
    assert export_ply(tmp_path / "e.ply", **g) == 0
    back = read_ply(tmp_path / "e.ply")
    assert back["sh"].shape == (0, 16, 3) and back["means"].shape == (0, 3)
    assert export_splat(tmp_path / "e.splat", **g) == 0
    assert read_splat(tmp_path / "e.splat")["means"].shape == (0, 3)
