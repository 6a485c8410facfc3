"""Learning-rate schedules."""

from __future__ import annotations

import math


def log_linear(step: float, lr_init: float, lr_final: float, max_steps: int) -> float:
    """3DGS exponential decay: log-linear interpolation from ``lr_init`` to ``lr_final`` over
    ``max_steps``; constant at ``lr_final`` afterwards (both must be > 0)."""
    if max_steps <= 0:
        return lr_final
    t = min(max(step / max_steps, 0.0), 1.0)
    return math.exp(math.log(lr_init) * (1.0 - t) + math.log(lr_final) * t)


def position_lr(
    iteration: float, lr_init: float, lr_final: float, start: int, steps: int, extent: float
) -> float:
    """DNGaussian's centre LR: ``log_linear(max(iteration - start, 0))`` times the scene extent."""
    return extent * log_linear(max(iteration - start, 0), lr_init, lr_final, steps)


def crossed(previous: float, position: float, mark: float) -> bool:
    """Whether the schedule passed ``mark`` in the step from ``previous`` to ``position``
    (for whole-iteration steps: ``position == mark``)."""
    return previous < mark <= position


def crossed_multiple(previous: float, position: float, interval: int) -> bool:
    """Whether the step from ``previous`` to ``position`` passed a multiple of ``interval``
    (for whole-iteration steps: ``position % interval == 0``)."""
    return interval > 0 and position // interval > previous // interval


class ScheduleClock:
    """Where the run is on its nominal schedule of ``total`` iterations.

    Without a budget or a limit the position of iteration ``i`` is ``i`` itself, so every part
    compares exactly as a plain iteration counter would (and a hook called with any iteration
    number sees that number). With ``budget_s`` the run is a deadline: the position of the
    current iteration is ``total`` x the elapsed fraction of the budget, and the run ends when
    the budget is spent, so the LR decay, densification window, depth starts and dropout ramp
    land at the same fractions of the budget whatever the machine's speed. With ``limit_s``
    the run is ``total`` iterations or ``limit_s`` seconds, whichever comes first: the
    position is whichever of the iteration and ``total`` x the elapsed fraction of the limit
    is further along. On a machine fast enough for the limit never to bind, that is the
    iteration itself (the run is the same as without a limit, bit for bit); on a slower one
    the schedule runs ahead of the iteration count from the moment time would run out first,
    and still completes by the limit. Seconds spent before the first iteration that count as
    training (:attr:`setup_s`: the learned matches) count towards the budget or limit but not
    towards its pace: the schedule spreads over the seconds left after them, so a run fast
    enough for its limit keeps the plain schedule from its first iteration. Parts compare
    schedule fields (those ``TrainConfig.with_iterations`` scales) against :meth:`position`
    and keep raw iteration counts for cadences (``densify.interval``, ``depth.every``)."""

    def __init__(
        self, total: int, budget_s: float | None = None, limit_s: float | None = None
    ) -> None:
        """``total``: the nominal schedule length (``config.iterations``); ``budget_s``: a
        deadline (``time_budget_s``); ``limit_s``: a limit (``time_limit_s``; unused with a
        budget)."""
        self.total = total
        self.budget_s = budget_s
        self.limit_s = None if budget_s is not None else limit_s
        self._position: float = 0
        self._previous: float = 0
        self.limited = False
        """Whether the time limit has bound: the schedule ran ahead of the iteration count."""
        self.setup_s = 0.0
        """Training seconds spent before the first iteration (the trainer sets it; a checkpoint
        keeps it): counted by :meth:`finished`, left out of the schedule's pace."""

    def _seconds(self) -> float | None:
        return self.budget_s if self.budget_s is not None else self.limit_s

    def _at(self, elapsed_s: float, iteration: int) -> float:
        """The position of ``iteration`` begun after ``elapsed_s`` under a budget or limit."""
        seconds = self._seconds()
        assert seconds is not None
        setup = min(self.setup_s, seconds)
        span = seconds - setup
        done = max(elapsed_s - setup, 0.0)
        timed = float(self.total) if span <= 0 else min(float(self.total), self.total * done / span)
        if self.budget_s is not None:
            return timed
        if iteration >= timed:  # the iteration count is ahead: the plain schedule, exactly
            return iteration
        self.limited = True
        return timed

    def start(self, elapsed_s: float, iteration: int = 0) -> None:
        """Set the position of a run (re)started after ``elapsed_s`` training seconds and
        ``iteration`` iterations."""
        if self._seconds() is not None:
            self._position = self._previous = self._at(elapsed_s, iteration)

    def advance(self, elapsed_s: float, iteration: int) -> None:
        """Move to ``iteration`` (1-based), begun after ``elapsed_s`` training seconds."""
        if self._seconds() is not None:
            self._previous = self._position
            self._position = self._at(elapsed_s, iteration)

    def finished(self, iteration: int, elapsed_s: float) -> bool:
        """Whether the run is over: ``total`` iterations done, the budget spent, or the limit
        reached."""
        if self.budget_s is not None:
            return elapsed_s >= self.budget_s
        if self.limit_s is not None and elapsed_s >= self.limit_s:
            return True
        return iteration >= self.total

    def position(self, iteration: int) -> float:
        """The schedule position of (1-based) ``iteration``, the current one under a budget
        or a limit."""
        return iteration if self._seconds() is None else self._position

    def previous(self, iteration: int) -> float:
        """The schedule position of the iteration before ``iteration``."""
        return iteration - 1 if self._seconds() is None else self._previous

    def crossed(self, mark: float, iteration: int) -> bool:
        """Whether ``iteration`` passed schedule position ``mark`` (whole iterations:
        ``iteration == mark``)."""
        return crossed(self.previous(iteration), self.position(iteration), mark)

    def crossed_multiple(self, interval: int, iteration: int) -> bool:
        """Whether ``iteration`` passed a multiple of ``interval`` (whole iterations:
        ``iteration % interval == 0``)."""
        return crossed_multiple(self.previous(iteration), self.position(iteration), interval)
