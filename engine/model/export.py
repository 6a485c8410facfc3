"""A model's export files: the INRIA .ply and the .splat, neural colours baked into SH first."""

from __future__ import annotations

from pathlib import Path

from torch import Tensor

from sparsesplat.api.names import ARTIFACT_FILES
from sparsesplat.engine.camera import Camera
from sparsesplat.engine.color.models import ColorModel, NeuralColor
from sparsesplat.engine.export import export_ply, export_splat
from sparsesplat.engine.gaussians import Gaussians
from sparsesplat.engine.model.sh import baking_psnr, model_sh


def export_model(
    out_dir: Path,
    gaussians: Gaussians,
    color: ColorModel,
    cameras: list[Camera],
    background: Tensor,
) -> tuple[dict[str, Path], float | None]:
    """Write ``model.ply`` and ``model.splat`` into ``out_dir`` with the SH of
    :func:`~sparsesplat.engine.model.sh.model_sh` (``cameras``: the training views the bake
    favours). Returns the paths by kind and, for neural colour, the PSNR of the baked renders
    against the neural ones over ``cameras`` on ``background`` (None for SH colour, exact)."""
    sh = model_sh(gaussians, color, cameras)
    g = gaussians
    args = (
        g.means.detach().cpu(),
        g.log_scales.detach().cpu(),
        g.quats.detach().cpu(),
        g.opacity_logits.detach().cpu(),
        sh,
    )
    out = {kind: out_dir / ARTIFACT_FILES[kind] for kind in ("ply", "splat")}
    export_ply(out["ply"], *args)
    export_splat(out["splat"], *args)
    if not isinstance(color, NeuralColor):
        return out, None
    return out, baking_psnr(g, color, sh, cameras, background)
