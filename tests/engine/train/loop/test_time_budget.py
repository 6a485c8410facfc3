"""A time budget is a deadline: the run trains until the budget is spent, and its schedule (LR
decay, depth starts, densification window, dropout ramp) follows the elapsed fraction of the
budget. Driven by a fake time source, so a wrong budget rule fails whatever the machine."""

from __future__ import annotations

import pytest

from sparsesplat.engine.synthetic import make_scene
from sparsesplat.engine.train import Trainer
from sparsesplat.engine.train.config import ConfigError, TrainConfig
from sparsesplat.engine.train.config.presets import PRESET_ITERATIONS
from sparsesplat.engine.train.loop.schedule import ScheduleClock, position_lr
from sparsesplat.engine.train.run import RunSpec, plan_run
from tests.engine.train.loop.test_trainer_parts import small

STEP_S = 0.5
"""Training seconds each iteration takes on the fake clock."""


class FakeTime:
    """A time source that advances only when an iteration runs."""

    def __init__(self) -> None:
        """Start at 1000 s (any origin: only differences count)."""
        self.now = 1000.0

    def __call__(self) -> float:
        """The current fake time."""
        return self.now


def clocked_config(nominal: int, **clock: float | None) -> TrainConfig:
    """The smoke config with a ``nominal``-iteration schedule whose phases the tests of the
    schedule clock watch (centre LR decay over all of it, soft depth from a quarter,
    densification between a tenth and a half), plus ``clock`` (``time_budget_s`` or
    ``time_limit_s``)."""
    return small(
        iterations=nominal, dropout=True,
        lr_means_start=0, lr_means_steps=nominal, soft_depth_start=nominal // 4,
        densify_from=nominal // 10, densify_until=nominal // 2, densify_interval=5, **clock,
    )  # fmt: skip


def _budget_run(budget_s: float, nominal: int) -> tuple[Trainer, dict[int, dict[str, float]]]:
    """Train the smoke config under ``budget_s`` with ``nominal`` schedule iterations, each
    iteration taking STEP_S fake seconds; returns the trainer and, per iteration, its
    schedule position, centre LR, depth passes run and dropout rate."""
    scene, priors = make_scene(seed=0)
    config = clocked_config(nominal, time_budget_s=budget_s)
    fake = FakeTime()
    t = Trainer(scene, config, priors, time_source=fake)
    seen: dict[int, dict[str, float]] = {}
    step, depth_loss = t._step, t.depth.depth_loss  # type: ignore[union-attr]

    def timed_step() -> None:
        step()
        means = next(g for g in t.optimizer.param_groups if g["name"] == "means")
        seen[t.iteration] |= {"position": t.clock.position(t.iteration), "lr": means["lr"]}
        fake.now += STEP_S

    def counted_depth_loss(*args, **kwargs):  # type: ignore[no-untyped-def]
        seen.setdefault(t.iteration, {"passes": 0})["passes"] += 1
        return depth_loss(*args, **kwargs)

    def before(it: int) -> None:
        seen.setdefault(it, {"passes": 0})

    t._step = lambda: (before(t.iteration), timed_step())[-1]  # type: ignore[method-assign]
    t.depth.depth_loss = counted_depth_loss  # type: ignore[method-assign,union-attr]
    return t, seen


def test_a_budget_trains_until_it_is_spent_on_the_budgets_schedule() -> None:
    budget, nominal = 150.0, 40
    t, seen = _budget_run(budget, nominal)
    result = t.run()
    # 150 s at 0.5 s per iteration: exactly 300 iterations, whatever the nominal length.
    assert result.iteration == len(seen) == round(budget / STEP_S) == 300
    assert result.seconds == budget
    assert result.metrics["time_budget_s"] == budget and result.metrics["seconds"] == budget
    for k, row in seen.items():
        # iteration k begins after (k - 1) x 0.5 s: the position is that fraction of 40
        want = nominal * (k - 1) * STEP_S / budget
        assert row["position"] == pytest.approx(want, rel=1e-12, abs=1e-12), k
        lr = position_lr(want, 0.016, 0.00016, 0, nominal, t.extent)
        assert row["lr"] == pytest.approx(lr, rel=1e-9), k
    # the soft-depth pass joins at position > 10 of 40, i.e. after a quarter of the budget
    first_soft = min(k for k, row in seen.items() if row["passes"] == 2)
    assert first_soft == 1 + int(10 / nominal * budget / STEP_S) + 1 == 77
    assert all(seen[k]["passes"] <= 1 for k in range(1, first_soft))
    # the hard pass starts after position 1 (the compressed start of 0): (k - 1) / 7.5 > 1
    assert min(k for k, row in seen.items() if row["passes"] >= 1) == 9
    # the centre LR decayed over the whole budget, not over the first 40 iterations
    assert seen[40]["lr"] > seen[150]["lr"] > seen[300]["lr"]
    assert seen[300]["lr"] == pytest.approx(
        position_lr(nominal * 299 * STEP_S / budget, 0.016, 0.00016, 0, nominal, t.extent)
    )


def test_densification_stops_at_the_budgets_fraction_of_the_window() -> None:
    budget, nominal = 30.0, 40  # 60 iterations; densify while 4 < position < 20
    t, _ = _budget_run(budget, nominal)
    counts: list[tuple[int, int]] = []
    assert t.densify is not None
    post = t.densify.step_post_backward

    def spy(iteration, gaussians, *args, **kwargs):  # type: ignore[no-untyped-def]
        before = len(gaussians)
        post(iteration, gaussians, *args, **kwargs)
        counts.append((iteration, len(gaussians) - before))

    t.densify.step_post_backward = spy  # type: ignore[method-assign]
    t.run()
    changed = [k for k, d in counts if d != 0]
    # position(k) = 40 (k - 1) / 60 crosses 20 at k = 31: no densification after that
    assert changed and max(changed) <= 30
    assert all(4 < nominal * (k - 1) / 60 < 20 for k in changed)


def test_without_a_budget_the_position_is_the_iteration() -> None:
    clock = ScheduleClock(40)
    clock.advance(123.0, 7)  # elapsed time does not matter
    assert (clock.position(7), clock.previous(7)) == (7, 6)
    assert clock.crossed(7, 7) and not clock.crossed(8, 7)
    assert clock.crossed_multiple(5, 10) and not clock.crossed_multiple(5, 11)
    assert clock.finished(40, 0.0) and not clock.finished(39, 1e9)


def test_a_budget_and_an_iteration_count_are_exclusive() -> None:
    with pytest.raises(ConfigError, match="either iterations or a time budget"):
        plan_run(RunSpec("llff", iterations=100, time_budget_s=60.0), None)
    with pytest.raises(ConfigError, match="positive number of seconds"):
        plan_run(RunSpec("llff", time_budget_s=0.0), None)
    plan = plan_run(RunSpec("llff", time_budget_s=90.0), None)
    # the nominal schedule is the preset's default length; the deadline is the config's
    assert (plan.config.iterations, plan.config.time_budget_s) == (PRESET_ITERATIONS["llff"], 90.0)
