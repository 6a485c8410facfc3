"""The initial model: Gaussians at the initial points and the colour model the config asks for."""

from __future__ import annotations

import torch
from torch import Tensor

from sparsesplat.engine.color.models import ColorModel, NeuralColor, SHColor
from sparsesplat.engine.color.sh import C0
from sparsesplat.engine.gaussians import Gaussians
from sparsesplat.engine.train.config import TrainConfig


def initial_model(
    cfg: TrainConfig,
    points: Tensor,
    colours: Tensor | None,
    generator: torch.Generator,
    device: torch.device,
) -> tuple[Gaussians, ColorModel]:
    """Gaussians at ``points`` (N, 3) with ``cfg.init.opacity`` and the colour model of
    ``cfg.color`` (its random draws from ``generator``, the neural field's first); an SH model
    starts from ``colours`` (N, 3) as its DC term when the init gave them."""
    color: ColorModel
    if cfg.color.model == "neural":
        color = NeuralColor.create(
            points,
            generator,
            log2_table_size=cfg.color.hash_log2_size,
            finest_resolution=cfg.color.hash_finest_resolution,
            view_degree=cfg.color.view_degree,
            view_interval=cfg.color.view_degree_interval or 0,
        )
        color.field.to(device)
    else:
        color = SHColor(cfg.color.sh_degree, cfg.color.sh_degree_interval)
    extra = color.init_per_gaussian(len(points), generator)
    if colours is not None and "sh_dc" in extra:  # the pixels' colours as SH DC
        extra["sh_dc"] = ((colours - 0.5) / C0).unsqueeze(1)
    gaussians = Gaussians.from_points(
        points.to(device),
        cfg.init.opacity,
        {k: v.to(device) for k, v in extra.items()},
    )
    return gaussians, color
