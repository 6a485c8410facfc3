"""The run's one Adam optimizer: its parameter groups (the Gaussians' tables and the colour
model's weights) and the centres' learning-rate schedule."""

from __future__ import annotations

from typing import Any

import torch

from sparsesplat.engine.color.models import ColorModel
from sparsesplat.engine.gaussians import Gaussians
from sparsesplat.engine.train.config import OptimConfig
from sparsesplat.engine.train.loop.schedule import position_lr


def make_optimizer(
    cfg: OptimConfig, gaussians: Gaussians, color: ColorModel, extent: float
) -> torch.optim.Adam:
    """One group per Gaussian table (named as the table) and the colour model's groups, at
    ``cfg``'s learning rates (the centres' scaled by the scene ``extent``)."""
    lrs = {
        "means": cfg.lr_means_init * extent,
        "log_scales": cfg.lr_scaling,
        "quats": cfg.lr_rotation,
        "opacity_logits": cfg.lr_opacity,
        "sh_dc": cfg.lr_sh,
        "sh_rest": cfg.lr_sh / 20.0,
    }
    groups: list[dict[str, Any]] = [
        {"name": name, "params": [p], "lr": lrs[name]} for name, p in gaussians.params.items()
    ]
    groups += color.param_groups({"hash_grid": cfg.lr_hash_grid, "mlp": cfg.lr_mlp})
    # fused: one kernel per tensor, several times faster than the default on CPU (the hash
    # table is millions of entries) and deterministic, so resumed runs stay bit-identical.
    return torch.optim.Adam(groups, lr=0.0, eps=cfg.adam_eps, fused=True)


def set_position_lr(
    optimizer: torch.optim.Optimizer, cfg: OptimConfig, position: float, extent: float
) -> None:
    """Set the centres' learning rate for schedule ``position`` (DNGaussian's log-linear
    decay, :func:`~sparsesplat.engine.train.loop.schedule.position_lr`)."""
    for group in optimizer.param_groups:
        if group["name"] == "means":
            group["lr"] = position_lr(
                position,
                cfg.lr_means_init,
                cfg.lr_means_final,
                cfg.lr_means_start,
                cfg.lr_means_steps,
                extent,
            )
