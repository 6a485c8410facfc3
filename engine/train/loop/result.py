"""What a run returns (:class:`TrainResult`) and what it says about a time limit that bound it."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sparsesplat.engine.train.config import TrainConfig
from sparsesplat.engine.train.loop.schedule import ScheduleClock


@dataclass
class TrainResult:
    """What a finished (or cleanly stopped) run returns."""

    metrics: dict[str, Any]
    """Final held-out metrics (psnr, ssim, lpips, avge; None where unavailable) plus seconds,
    iterations, n_gaussians, coverage, ``views`` (each held-out view's psnr, ssim, lpips and
    coverage, by name) and, for neural colour, the SH baking PSNR."""
    artifacts: dict[str, Path]
    """Written files by kind: checkpoint, metrics, series_json/csv/png, ply, splat."""
    seconds: float
    """Training seconds (evaluation and checkpoint time excluded)."""
    n_gaussians: int
    """Gaussians at the end."""
    records: list[dict[str, Any]] = field(default_factory=list)
    """The error-vs-time series (ProgressRecord dicts)."""
    stopped: bool = False
    """True when the progress callback asked the run to stop before the last iteration."""
    iteration: int = 0
    """Iterations completed."""


def limit_warning(limit: float, iteration: int, total: int, elapsed_s: float) -> str:
    """What the time limit ``limit`` (s) did to a run it bound (``ScheduleClock.limited``):
    ``iteration`` of ``total`` iterations done in ``elapsed_s`` training seconds."""
    way_out = "a run that asks for a number of iterations trains them all"
    if iteration < total:
        return (
            f"the run reached its time limit ({limit:g} s of training) after "
            f"{iteration} of {total} iterations; its schedule was compressed to end "
            f"there (this machine trains slower than the one the preset's length was "
            f"chosen on; {way_out})"
        )
    # Training fell behind the limit's pace for a while (a slow stretch: another process
    # on the machine, say), so the schedule ran ahead of the iteration count there, and
    # then caught up: every iteration ran, but not on the plain schedule.
    return (
        f"training ran slower than its time limit's pace ({total} iterations in "
        f"{limit:g} s) for a while, so the schedule ran ahead of the iteration count "
        f"there; all {total} iterations finished, in {elapsed_s:.0f} s, but the "
        f"result is not the plain schedule's (other work on the machine slows training "
        f"too; {way_out})"
    )


def note_time(
    metrics: dict[str, Any],
    config: TrainConfig,
    clock: ScheduleClock,
    iteration: int,
    elapsed_s: float,
    stopped: bool,
) -> None:
    """Add to a run's final ``metrics`` its time budget and time limit (against the seconds
    used, for the job's report), and the limit's warning when it bound a run that finished."""
    if config.time_budget_s is not None:
        metrics["time_budget_s"] = config.time_budget_s
    limit = config.time_limit_s
    if limit is not None:
        metrics["time_limit_s"] = limit
        metrics["time_limited"] = clock.limited
        if clock.limited and not stopped:
            warning = limit_warning(limit, iteration, config.iterations, elapsed_s)
            metrics.setdefault("warnings", []).append(warning)
