"""A time limit caps a run at a number of training seconds without changing a run it does not
bind: the schedule follows whichever of the iteration count and the elapsed fraction of the
limit is further along. Driven by a fake time source, so a wrong rule fails whatever the
machine."""

from __future__ import annotations

import pytest
import torch

from sparsesplat.engine.synthetic import make_scene
from sparsesplat.engine.train import Trainer, TrainResult
from sparsesplat.engine.train.config import ConfigError
from sparsesplat.engine.train.config.presets import DEFAULT_TIME_LIMIT_S, PRESET_ITERATIONS
from sparsesplat.engine.train.loop.schedule import ScheduleClock, position_lr
from sparsesplat.engine.train.run import RunSpec, plan_run
from tests.engine.train.loop.test_time_budget import STEP_S, FakeTime, clocked_config

NOMINAL = 40
"""The schedule length of the runs below (densification while 4 < position < 20)."""


def _run(
    limit_s: float | None, step_s: dict[int, float] | None = None, setup_s: float = 0.0
) -> tuple[Trainer, TrainResult, dict[int, dict[str, float]]]:
    """Train the smoke config for NOMINAL iterations under ``limit_s``, each iteration taking
    STEP_S fake seconds (or ``step_s[k]`` for iteration k), after ``setup_s`` seconds counted
    as training before the first (as the trainer counts its matching); returns the trainer and
    its result after the run and, per iteration, its schedule position, centre LR and the
    Gaussian count densification left."""
    scene, priors = make_scene(seed=0)
    config = clocked_config(NOMINAL, time_limit_s=limit_s)
    fake = FakeTime()
    t = Trainer(scene, config, priors, time_source=fake)
    t.elapsed_s = t.clock.setup_s = setup_s  # what the trainer does with its matches' seconds
    seen: dict[int, dict[str, float]] = {}
    step = t._step

    def timed_step() -> None:
        step()
        means = next(g for g in t.optimizer.param_groups if g["name"] == "means")
        seen[t.iteration] = {
            "position": t.clock.position(t.iteration),
            "lr": means["lr"],
            "n": len(t.gaussians),
        }
        fake.now += (step_s or {}).get(t.iteration, STEP_S)

    t._step = timed_step  # type: ignore[method-assign]
    return t, t.run(), seen


def test_a_limit_that_does_not_bind_leaves_the_run_bit_for_bit() -> None:
    # 40 iterations take 20 fake seconds: a 21 s limit never binds
    limited, result, seen = _run(21.0)
    plain, plain_result, plain_seen = _run(None)
    assert limited.iteration == plain.iteration == NOMINAL
    assert all(type(row["position"]) is int and row["position"] == k for k, row in seen.items())
    assert seen == plain_seen
    for name, value in plain.gaussians.params.items():
        assert torch.equal(limited.gaussians.params[name], value), name
    metrics = result.metrics
    assert metrics["time_limit_s"] == 21.0 and metrics["time_limited"] is False
    assert not metrics.get("warnings")
    assert "time_limit_s" not in plain_result.metrics


def test_seconds_before_the_first_iteration_count_towards_the_limit_not_its_pace() -> None:
    """5 s of matching, then 40 iterations of 0.5 s under a 26 s limit: the limit's pace over
    the 21 s left (40 in 21 s) never binds, so the run is the plain one bit for bit and says
    nothing. Counted from zero, 5 s would have put the schedule 7.7 positions ahead at the first
    iteration and reported a slow stretch."""
    timed, result, seen = _run(26.0, setup_s=5.0)
    plain, _, plain_seen = _run(None)
    assert seen == plain_seen
    for name, value in plain.gaussians.params.items():
        assert torch.equal(timed.gaussians.params[name], value), name
    assert result.metrics["seconds"] == pytest.approx(25.0)
    assert result.metrics["time_limited"] is False and not result.metrics.get("warnings")
    # A limit the run cannot make after its setup still ends it on time.
    short, short_result, _ = _run(15.0, setup_s=5.0)
    assert short.iteration == 20 and short_result.metrics["time_limited"] is True


def test_a_clock_spreads_its_schedule_over_the_seconds_left_after_setup() -> None:
    clock = ScheduleClock(40, limit_s=10.0)
    clock.setup_s = 2.0
    clock.advance(2.0, 1)  # nothing of the 8 s left is spent yet
    assert clock.position(1) == 1 and not clock.limited
    clock.advance(6.0, 14)  # half of the 8 s: 20 of 40, ahead of 14
    assert clock.position(14) == 20.0 and clock.limited
    assert not clock.finished(14, 9.9) and clock.finished(14, 10.0)
    over = ScheduleClock(40, limit_s=10.0)
    over.setup_s = 12.0  # setup longer than the limit: the schedule's end, and the run is over
    over.advance(12.0, 1)
    assert over.position(1) == 40.0 and over.finished(1, 12.0)


def test_a_checkpoint_keeps_the_setup_seconds() -> None:
    from sparsesplat.engine.train.loop.state import restore_trainer, trainer_state

    scene, priors = make_scene(seed=0)
    config = clocked_config(NOMINAL, time_limit_s=30.0)
    t = Trainer(scene, config, priors)
    t.clock.setup_s = 2.5
    state = trainer_state(t)
    again = Trainer(scene, config, priors)
    restore_trainer(again, state)
    assert again.clock.setup_s == 2.5
    del state["setup_s"]  # a checkpoint written before the setup seconds were kept
    restore_trainer(again, state)
    assert again.clock.setup_s == 0.0


def test_a_slow_stretch_that_the_run_makes_up_is_reported_as_such() -> None:
    """Iterations 2-4 take 2.2 s each (a slow stretch), the rest 0.5 s: under a 30 s limit the
    schedule runs ahead of the iteration count from iteration 3 until the count catches up,
    and all 40 iterations finish in 25.1 s (37 x 0.5 + 3 x 2.2). The result says the limit
    bound the schedule, and its warning says that every iteration ran, not that the run ended
    at the limit."""
    t, result, seen = _run(30.0, step_s={2: 2.2, 3: 2.2, 4: 2.2})
    metrics = result.metrics
    assert t.iteration == NOMINAL and metrics["seconds"] == pytest.approx(25.1)
    assert metrics["time_limited"] is True
    # iteration 3 begins after 0.5 + 2.2 s: 40 x 2.7 / 30 = 3.6, ahead of 3
    assert seen[3]["position"] == pytest.approx(NOMINAL * 2.7 / 30.0, rel=1e-12)
    assert seen[NOMINAL]["position"] == NOMINAL  # the count caught up
    (warning,) = metrics["warnings"]
    assert "all 40 iterations finished, in 25 s" in warning, warning
    assert "reached its time limit" not in warning


def test_a_limit_that_binds_ends_the_run_on_time_with_its_whole_schedule() -> None:
    limit = 10.0  # 20 iterations of 0.5 s, half the nominal 40
    t, result, seen = _run(limit)
    metrics = result.metrics
    assert t.iteration == len(seen) == round(limit / STEP_S) == 20
    assert metrics["seconds"] == limit and metrics["time_limited"] is True
    assert any("time limit (10 s of training) after 20 of 40" in w for w in metrics["warnings"])
    for k, row in seen.items():
        # iteration k begins after (k - 1) x 0.5 s; the limit's fraction of 40 is 2 (k - 1),
        # ahead of k from k = 3 on
        timed = NOMINAL * (k - 1) * STEP_S / limit
        assert row["position"] == pytest.approx(max(k, timed), rel=1e-12), k
        lr = position_lr(max(k, timed), 0.016, 0.00016, 0, NOMINAL, t.extent)
        assert row["lr"] == pytest.approx(lr, rel=1e-9), k
    # the centre LR reached the end of its decay, as a full run's does
    assert seen[20]["position"] == pytest.approx(38.0)
    # densification ran only inside the window's positions (4, 20), i.e. iterations 3-10
    grew = [k for k in seen if k > 1 and seen[k]["n"] != seen[k - 1]["n"]]
    assert grew and all(4 < seen[k]["position"] < 20 for k in grew)


def test_a_resumed_clock_takes_up_the_iteration_count() -> None:
    clock = ScheduleClock(40, limit_s=10.0)
    clock.start(1.0, 12)  # the limit's fraction (4) is behind iteration 12
    assert clock.position(12) == 12 and not clock.limited
    clock.advance(1.5, 13)
    assert (clock.previous(13), clock.position(13)) == (12, 13)
    clock.advance(5.0, 14)  # 20 of 40 is ahead of 14
    assert clock.position(14) == 20.0 and clock.limited
    assert not clock.finished(14, 9.9) and clock.finished(14, 10.0) and clock.finished(40, 0.0)


def test_a_budget_overrules_a_limit() -> None:
    clock = ScheduleClock(40, budget_s=20.0, limit_s=10.0)
    clock.advance(15.0, 2)
    assert clock.position(2) == 30.0 and not clock.finished(2, 15.0)


def test_default_runs_carry_the_limit_and_asked_lengths_do_not() -> None:
    plan = plan_run(RunSpec("llff"), None)
    assert plan.config.iterations == PRESET_ITERATIONS["llff"]
    assert plan.config.time_limit_s == DEFAULT_TIME_LIMIT_S <= 600.0
    assert plan_run(RunSpec("llff", iterations=3000), None).config.time_limit_s is None
    assert plan_run(RunSpec("dtu", overrides={"iterations": 900}), None).config.time_limit_s is None
    budgeted = plan_run(RunSpec("blender", time_budget_s=120.0), None).config
    assert (budgeted.time_budget_s, budgeted.time_limit_s) == (120.0, None)
    off = plan_run(RunSpec("llff", overrides={"time_limit_s": None}), None).config
    assert off.time_limit_s is None and off.iterations == PRESET_ITERATIONS["llff"]
    longer = plan_run(RunSpec("llff", overrides={"time_limit_s": 1200}), None).config
    assert longer.time_limit_s == 1200.0


@pytest.mark.parametrize("value", [0, -5.0, float("inf"), float("nan")])
def test_a_limit_must_be_a_positive_number_of_seconds(value: float) -> None:
    with pytest.raises(ConfigError, match="time_limit_s must be a positive number"):
        plan_run(RunSpec("llff", overrides={"time_limit_s": value}), None)


def test_a_limit_and_a_budget_together_are_refused() -> None:
    with pytest.raises(ConfigError, match=r"either a time budget .* or a time limit"):
        plan_run(RunSpec("llff", overrides={"time_limit_s": 60, "time_budget_s": 90}), None)
