"""The compact ``.splat`` format of antimatter15's WebGL viewer (and the viewers that copied it).

Each Gaussian is one 32-byte little-endian record, no header:
``position 3 x float32 | scale 3 x float32 (linear, not log) | RGBA 4 x uint8 | rotation 4 x
uint8``. RGB is the view-independent (DC) colour, A the activated opacity, both scaled to
0..255; the rotation is the unit wxyz quaternion mapped from [-1, 1] to 0..255 as q*128 + 128.
Records are sorted by importance, volume x opacity, largest first, so a viewer that streams
the file shows the big opaque splats before the small faint ones.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from sparsesplat.engine.export._gaussians import check_gaussians
from sparsesplat.engine.export.errors import ExportError
from sparsesplat.engine.export.sh_eval import dc_to_rgb

SPLAT_DTYPE = np.dtype(
    [("position", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)), ("rot", "u1", (4,))]
)
"""numpy view of one record; ``SPLAT_DTYPE.itemsize == 32``."""


def _to_u8(x: Tensor) -> Tensor:
    """Map [0, 1] to 0..255 with rounding and clipping."""
    return (x * 255.0).round().clamp(0, 255).to(torch.uint8)


def export_splat(
    path: str | Path,
    means: Tensor,
    log_scales: Tensor,
    quats: Tensor,
    opacity_logits: Tensor,
    sh: Tensor,
) -> int:
    """Write Gaussians as a ``.splat`` file; returns the number of records written.

    Only the DC term of ``sh`` (N, K, 3) is used. Non-finite Gaussians are dropped (logged);
    bad shapes raise :class:`ExportError`.
    """
    path = Path(path)
    g = check_gaussians(means, log_scales, quats, opacity_logits, sh, what=f"splat export {path}")
    n = g.means.shape[0]
    opacity = torch.sigmoid(g.opacity_logits)
    # Importance in log space (sum of log scales + log opacity) so huge scales cannot overflow.
    importance = g.log_scales.sum(1) + torch.log(opacity.clamp_min(1e-30))
    order = torch.argsort(importance, descending=True, stable=True)

    norm = g.quats.norm(dim=1, keepdim=True)
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(n, 4)
    # A zero quaternion has no rotation to export; write the identity instead of NaNs.
    unit = torch.where(norm > 1e-12, g.quats / norm.clamp_min(1e-12), identity)

    records = np.zeros(n, dtype=SPLAT_DTYPE)
    records["position"] = g.means[order].numpy()
    records["scale"] = torch.exp(g.log_scales[order]).numpy()
    rgb = dc_to_rgb(g.sh[order, 0, :]).clamp(0.0, 1.0)
    records["rgba"] = _to_u8(torch.cat([rgb, opacity[order, None]], dim=1)).numpy()
    records["rot"] = (unit[order] * 128.0 + 128.0).round().clamp(0, 255).to(torch.uint8).numpy()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(records.tobytes())
    return n


def read_splat(path: str | Path) -> dict[str, Tensor]:
    """Decode a ``.splat`` file: ``means, scales (linear), rgba (0..1), quats (unit, wxyz)``."""
    path = Path(path)
    data = path.read_bytes()
    if len(data) % SPLAT_DTYPE.itemsize:
        raise ExportError(f"{path}: size {len(data)} is not a multiple of 32-byte splat records")
    rec = np.frombuffer(data, dtype=SPLAT_DTYPE)
    quats = (torch.from_numpy(rec["rot"].astype(np.float32)) - 128.0) / 128.0
    return {
        "means": torch.from_numpy(rec["position"].copy()),
        "scales": torch.from_numpy(rec["scale"].copy()),
        "rgba": torch.from_numpy(rec["rgba"].astype(np.float32) / 255.0),
        "quats": torch.nn.functional.normalize(quats, dim=1),
    }
