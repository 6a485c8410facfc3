"""Progress events the trainer emits: error-vs-time records and state changes."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

STATES = (
    "initializing",
    "training",
    "evaluating",
    "checkpointing",
    "stopped",
    "finished",
    "failed",
)
"""Every state a run can report."""


@dataclass
class ProgressRecord:
    """One point of the error-vs-time curve."""

    iteration: int
    """Iterations completed."""
    elapsed_s: float
    """Training seconds so far, EXCLUDING time spent evaluating and checkpointing."""
    train_loss: float | None
    """Mean photometric loss over the iterations since the previous record."""
    psnr: float | None
    """Mean held-out PSNR (None when the scene has no held-out views)."""
    ssim: float | None
    """Mean held-out SSIM."""
    lpips: float | None
    """Mean held-out LPIPS (None when the weights are unavailable)."""
    avge: float | None
    """AVGE from the three means (None without LPIPS)."""
    n_gaussians: int
    """Number of Gaussians at this point."""
    eval_s: float = 0.0
    """Seconds this evaluation took (not counted in elapsed_s)."""
    final: bool = False
    """True for the record taken at the end of training (all held-out views)."""
    views: int = 0
    """Held-out views this record scored: at most ``record.eval_max_views`` for the interim
    records (the same ones each time), all of them for the final record."""
    kind: str = field(default="record", init=False)
    """Event discriminator: always 'record'."""

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dict."""
        return dataclasses.asdict(self)


@dataclass
class StateChange:
    """The run entered a new state."""

    state: str
    """One of :data:`STATES`."""
    iteration: int
    """Iterations completed when the state changed."""
    message: str = ""
    """Human-readable detail (e.g. the error for 'failed')."""
    kind: str = field(default="state", init=False)
    """Event discriminator: always 'state'."""

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dict."""
        return dataclasses.asdict(self)


ProgressEvent = ProgressRecord | StateChange
"""What the progress callback receives."""

ProgressCallback = Callable[[ProgressEvent], Any]
"""Callback type: return True or 'stop' to end the run cleanly (with a checkpoint)."""


def wants_stop(answer: Any) -> bool:
    """Interpret a callback's return value: True or 'stop' (any case) asks the run to stop."""
    return answer is True or (isinstance(answer, str) and answer.lower() == "stop")
