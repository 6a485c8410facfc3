"""What the training loop hands its parts, and the stage timer they report to.

A part (densification, the depth regulariser, the divergence guard, the recorder) owns its
settings (its own section of :class:`TrainConfig`, e.g. ``config.densify``), its
running state (``state_dict`` / ``load_state_dict``, merged into the checkpoint's top level)
and its hooks; the loop in ``trainer.py`` calls the hooks in the order the method runs them.
Tensors that a checkpoint load or a densification replaces (the Gaussians, the optimizer) are
passed to every hook call, never kept by a part.

A part a run does not need is not built (the trainer holds None), so a switched-off part
changes nothing, not even the order of the run's random draws. The loop's order of hooks::

    (model set-up)                 init_points: random box, or dense_init (init='dense')
    densify.step_pre_backward      clean-views pruning
    (draw the view)
    dtu.adjust_view                blackened target + background mask (dtu_background)
    depth.step_pre_photometric     hard and soft depth passes, own optimizer steps
                                   (auxiliary_step='joint': gradients kept for the one step)
    dtu.step_pre_photometric       background-alpha pass, own optimizer step (likewise)
    pseudo.step_pre_photometric    depth at a pseudo view, own optimizer step (pseudo.weight > 0)
    dropout.draw                   photometric_inputs: the kept rows (dropout)
    photometric render, loss
    consistency.extra_loss         added to the photometric loss (consistency_weight > 0)
    binocular.extra_loss           render from a shifted camera, warped back (binocular.weight > 0)
    guard.check_finite, backward
    scatter_output                 dropout: means2d.grad and radii back on all N rows
    densify.step_post_backward     statistics, (dtu.black_white), densify, opacity reset
    near_prune.step                delete Gaussians near the render path (near_prune)
    guard.before_step / optimizer step / guard.after_step
    recorder.record                when an evaluation is due (near_prune.eval_keep: the rows
                                   rendered for the held-out cameras)
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from sparsesplat.engine.camera import Camera
from sparsesplat.engine.losses import SSIMTarget

if TYPE_CHECKING:
    from sparsesplat.engine.gaussians import Gaussians
    from sparsesplat.engine.train.loop.guard import DivergenceGuard


@dataclass
class TrainView:
    """The training view one iteration uses."""

    index: int
    """Position in the scene's training list (and in the priors)."""
    camera: Camera
    """Its camera, on the run's device."""
    image: Tensor
    """Its (3, H, W) target."""
    ssim_target: SSIMTarget | None = None
    """The target's precomputed SSIM statistics (None: computed from ``image``)."""
    mask: Tensor | None = None
    """(H, W) bool background mask set by the DTU background part (None without it)."""


class StageTimer:
    """Accumulated seconds per stage of an iteration, when profiling is on (else free)."""

    def __init__(self, enabled: bool) -> None:
        """``enabled``: ``config.profile``."""
        self.enabled = enabled
        self.totals: dict[str, float] = {}
        """Seconds per stage name, summed over the iterations timed so far."""
        self._last = time.perf_counter()

    def start(self) -> None:
        """Start timing the first stage of an iteration."""
        self._last = time.perf_counter()

    def tick(self, stage: str) -> None:
        """Charge the time since the previous tick (or :meth:`start`) to ``stage``."""
        if self.enabled:
            now = time.perf_counter()
            self.totals[stage] = self.totals.get(stage, 0.0) + (now - self._last)
            self._last = now


@dataclass(frozen=True)
class AuxiliaryStep:
    """What an auxiliary pass before the photometric step (the depth passes, the DTU
    background-alpha pass) works on in one iteration: one object, so every such hook takes the
    same argument and the loop builds it once."""

    iteration: int
    """The 1-based iteration."""
    gaussians: Gaussians
    """The run's Gaussians (replaced by densification and checkpoint loads, so never kept)."""
    optimizer: torch.optim.Optimizer
    """The run's shared Adam optimizer."""
    view: TrainView
    """The iteration's training view (after ``dtu.adjust_view``)."""
    extent: float
    """The scene extent."""
    guard: DivergenceGuard
    """The divergence checks each pass's loss goes through."""
    timer: StageTimer
    """The stage timer the passes report to."""


def finish_auxiliary_pass(step: AuxiliaryStep, loss: Tensor, what: str, joint: bool) -> None:
    """End an auxiliary pass whose ``loss`` is computed: check it is finite (``what`` names it
    in the error), run its backward, then take its own optimizer step (and clear the
    gradients) when passes step separately; nothing more when ``joint``, so its gradients wait
    in ``.grad`` and join the photometric step."""
    step.guard.check_finite(loss.detach(), what, step.iteration)
    loss.backward()
    if not joint:
        step.optimizer.step()
        step.optimizer.zero_grad(set_to_none=True)
