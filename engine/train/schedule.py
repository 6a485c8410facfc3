"""Learning-rate schedules."""

from __future__ import annotations

import math


def log_linear(step: int, lr_init: float, lr_final: float, max_steps: int) -> float:
    """3DGS exponential decay: log-linear interpolation from ``lr_init`` to ``lr_final`` over
    ``max_steps``; constant at ``lr_final`` afterwards (both must be > 0)."""
    if max_steps <= 0:
        return lr_final
    t = min(max(step / max_steps, 0.0), 1.0)
    return math.exp(math.log(lr_init) * (1.0 - t) + math.log(lr_final) * t)


def position_lr(
    iteration: int, lr_init: float, lr_final: float, start: int, steps: int, extent: float
) -> float:
    """DNGaussian's centre LR: ``log_linear(max(iteration - start, 0))`` times the scene extent."""
    return extent * log_linear(max(iteration - start, 0), lr_init, lr_final, steps)
