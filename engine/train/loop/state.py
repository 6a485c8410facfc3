"""A run's checkpoint state: what the trainer and its parts hold, and putting it back.

Format version 1 (``engine.model.checkpoint.CHECKPOINT_VERSION``): the parts' entries
(``state_dict`` / ``load_state_dict`` of densification, the depth regulariser, the guard,
near-plane pruning, warp consistency) sit at the top level beside the model's
(``engine/model/checkpoint.py`` writes the file and keeps the finished model's share of it,
``MODEL_KEYS``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from sparsesplat.engine.color.models import NeuralColor, make_color_model
from sparsesplat.engine.gaussians import Gaussians
from sparsesplat.engine.model.checkpoint import CHECKPOINT_VERSION
from sparsesplat.engine.train.loop.optimizer import make_optimizer

if TYPE_CHECKING:
    from sparsesplat.engine.train.loop.trainer import Trainer


def trainer_state(t: Trainer) -> dict[str, Any]:
    """Everything needed to continue the run of ``t`` bit-for-bit on CPU."""
    g = t.gaussians
    return {
        "version": CHECKPOINT_VERSION,
        "config": t.config.to_dict(),
        "scene_name": t.scene.name,
        "iteration": t.iteration,
        "elapsed_s": t.elapsed_s,
        "setup_s": t.clock.setup_s,
        "extent": t.extent,
        "raster_near": t.raster_near,
        "background": t.background.cpu(),
        "gaussians": {k: v.detach().cpu() for k, v in g.params.items()},
        "grad_accum": g.grad_accum.cpu(),
        "grad_count": g.grad_count.cpu(),
        "max_radii": None,
        **(t.densify.state_dict() if t.densify is not None else {}),
        "color": t.color.state_dict(),
        "optimizer": t.optimizer.state_dict(),
        "generator": t.generator.get_state(),
        "view_stack": list(t.view_stack),
        "hard_ema": None,
        **(t.depth.state_dict() if t.depth is not None else {}),
        **t.guard.state_dict(),
        **({"init_note": t.init_note} if t.init_note is not None else {}),
        **(t.near_prune.state_dict() if t.near_prune is not None else {}),
        **(t.consistency.state_dict() if t.consistency is not None else {}),
        **(t.poses.state_dict() if t.poses is not None else {}),
        "records": list(t.records),
    }


def restore_trainer(t: Trainer, state: dict[str, Any]) -> None:
    """Put ``t`` (built for the same scene and config) where :func:`trainer_state` left it."""
    dev = t.device
    t.iteration = int(state["iteration"])
    t.elapsed_s = float(state["elapsed_s"])
    t.extent = float(state["extent"])
    t.gaussians = Gaussians({k: v.to(dev) for k, v in state["gaussians"].items()})
    t.gaussians.grad_accum = state["grad_accum"].to(dev)
    t.gaussians.grad_count = state["grad_count"].to(dev)
    if t.densify is not None:
        t.densify.load_state_dict(state)
    t.color = make_color_model(state["color"])
    if isinstance(t.color, NeuralColor):
        t.color.field.to(dev)
    t.optimizer = make_optimizer(t.config.optim, t.gaussians, t.color, t.extent)
    t.optimizer.load_state_dict(state["optimizer"])
    t.generator.set_state(state["generator"])
    t.view_stack = list(state["view_stack"])
    if t.depth is not None:
        t.depth.load_state_dict(state)
    t.guard.load_state_dict(state)
    t.init_note = state.get("init_note", t.init_note)
    if t.near_prune is not None:
        t.near_prune.load_state_dict(state)
    if t.consistency is not None:
        t.consistency.load_state_dict(state)
    if t.poses is not None:
        t.poses.load_state_dict(state)
    t.recorder.records = list(state["records"])
    # Checkpoints from before the setup seconds were kept: their run's clock had none.
    t.clock.setup_s = float(state.get("setup_s", 0.0))
    t.clock.start(t.elapsed_s, t.iteration)
