"""The standard 3DGS .ply (the INRIA layout most viewers and tools open) and a reader for it.

Layout: one ``vertex`` element, binary little endian, all properties float32, in this order:
``x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 f_rest_0 .. f_rest_{3(K-1)-1} opacity scale_0 scale_1
scale_2 rot_0 rot_1 rot_2 rot_3``. Normals are written as zeros (3DGS does the same). ``f_rest``
is channel-major: all higher-order coefficients of red, then green, then blue. Opacity is the
pre-sigmoid logit, scales are logs, the rotation is the wxyz quaternion as stored.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from sparsesplat.engine.export._gaussians import check_gaussians
from sparsesplat.engine.export.errors import ExportError
from sparsesplat.engine.export.sh_eval import degree_from_coeffs, num_coeffs

# PLY scalar type names -> numpy little-endian dtypes (both the old and the sized spellings).
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "<i2", "int16": "<i2", "ushort": "<u2", "uint16": "<u2",
    "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
    "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8",
}  # fmt: skip


def ply_property_names(degree: int) -> list[str]:
    """The INRIA vertex property list for SH ``degree`` (0..3), in file order."""
    n_rest = 3 * (num_coeffs(degree) - 1)
    return [
        *("x", "y", "z", "nx", "ny", "nz"),
        *(f"f_dc_{i}" for i in range(3)),
        *(f"f_rest_{i}" for i in range(n_rest)),
        "opacity",
        *(f"scale_{i}" for i in range(3)),
        *(f"rot_{i}" for i in range(4)),
    ]


def export_ply(
    path: str | Path,
    means: Tensor,
    log_scales: Tensor,
    quats: Tensor,
    opacity_logits: Tensor,
    sh: Tensor,
) -> int:
    """Write Gaussians as an INRIA-layout .ply; returns the number of Gaussians written.

    ``sh`` is (N, (d+1)^2, 3) with d in 0..3 (d = 0 for a DC-only model). Gaussians with any
    non-finite parameter are dropped (the count is logged). Raises :class:`ExportError` on bad
    shapes.
    """
    path = Path(path)
    g = check_gaussians(means, log_scales, quats, opacity_logits, sh, what=f"PLY export {path}")
    n = g.means.shape[0]
    # (N, K, 3) -> DC (N, 3) and channel-major rest (N, 3, K-1) flattened, as INRIA writes it.
    dc = g.sh[:, 0, :]
    rest = g.sh[:, 1:, :].transpose(1, 2).reshape(n, 3 * (g.sh.shape[1] - 1))
    columns = torch.cat(
        [g.means, torch.zeros(n, 3), dc, rest, g.opacity_logits[:, None], g.log_scales, g.quats],
        dim=1,
    )
    names = ply_property_names(g.degree)
    assert columns.shape[1] == len(names)
    header = "\n".join(
        [
            "ply",
            "format binary_little_endian 1.0",
            f"element vertex {n}",
            *(f"property float {name}" for name in names),
            "end_header",
        ]
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        f.write(header.encode("ascii") + b"\n")
        f.write(columns.numpy().astype("<f4", copy=False).tobytes())
    return n


def _parse_header(
    path: Path, data: bytes
) -> tuple[int, list[tuple[str, int, list[tuple[str, str]]]]]:
    """Return (byte offset of the body, [(element, count, [(property, dtype)])])."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ExportError(f"{path}: not a PLY file (missing 'ply' magic or 'end_header')")
    body = data.index(b"\n", end) + 1
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for raw in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        parts = raw.split()
        if not parts or parts[0] in ("comment", "obj_info"):
            continue
        if parts[0] == "format":
            if parts[1:2] != ["binary_little_endian"]:
                raise ExportError(f"{path}: PLY format {' '.join(parts[1:])} not supported")
        elif parts[0] == "element":
            elements.append((parts[1], int(parts[2]), []))
        elif parts[0] == "property":
            if not elements:
                raise ExportError(f"{path}: property before any element in the PLY header")
            if parts[1] == "list":
                raise ExportError(f"{path}: list property '{parts[-1]}' not supported")
            if parts[1] not in _PLY_TYPES:
                raise ExportError(f"{path}: unknown PLY property type '{parts[1]}'")
            elements[-1][2].append((parts[2], _PLY_TYPES[parts[1]]))
    return body, elements


def read_ply(path: str | Path) -> dict[str, Tensor]:
    """Read a 3DGS .ply back: ``means, log_scales, quats, opacity_logits, sh`` as float32.

    ``sh`` is (N, K, 3) with K inferred from the number of ``f_rest_*`` properties. Accepts the
    properties in any order and other float/integer types. Raises :class:`ExportError` when the
    file is not a binary little-endian PLY with the 3DGS vertex properties.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ExportError(f"{path}: cannot read PLY file: {exc}") from None
    offset, elements = _parse_header(path, data)
    vertex = None
    for name, count, props in elements:
        dtype = np.dtype([(p, t) for p, t in props])
        if name == "vertex":
            if len(data) < offset + count * dtype.itemsize:
                raise ExportError(f"{path}: file truncated ({count} vertices declared)")
            vertex = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
            break
        offset += count * dtype.itemsize
    if vertex is None:
        raise ExportError(f"{path}: no 'vertex' element in the PLY header")
    fields = set(vertex.dtype.names or ())
    n_rest = sum(1 for f in fields if f.startswith("f_rest_"))
    if n_rest % 3:
        raise ExportError(f"{path}: {n_rest} f_rest_* properties is not a multiple of 3")
    k = n_rest // 3 + 1
    try:
        degree_from_coeffs(k)
    except ValueError as exc:
        raise ExportError(f"{path}: {exc}") from None
    required = [n for n in ply_property_names(degree_from_coeffs(k)) if not n.startswith("n")]
    missing = [n for n in required if n not in fields]
    if missing:
        raise ExportError(f"{path}: missing vertex properties {missing[:6]}")

    def cols(*names: str) -> Tensor:
        stacked = np.stack([vertex[n].astype(np.float32) for n in names], axis=1)
        return torch.from_numpy(stacked.reshape(len(vertex), len(names)))

    n = len(vertex)
    dc = cols("f_dc_0", "f_dc_1", "f_dc_2")
    rest = cols(*(f"f_rest_{i}" for i in range(n_rest))) if n_rest else torch.zeros(n, 0)
    sh = torch.cat([dc[:, None, :], rest.reshape(n, 3, k - 1).transpose(1, 2)], dim=1)
    return {
        "means": cols("x", "y", "z"),
        "log_scales": cols("scale_0", "scale_1", "scale_2"),
        "quats": cols("rot_0", "rot_1", "rot_2", "rot_3"),
        "opacity_logits": cols("opacity")[:, 0],
        "sh": sh.contiguous(),
    }
