"""engine/denormals.py: inside ``flush_denormals()`` every compute thread flushes float32
denormals to zero, the previous mode comes back after it, and a CPU training run trains inside
it. The probe is an elementwise product whose exact result is denormal (1e-20 * 1e-20 = 1e-40,
below float32's smallest normal 1.18e-38): kept as a denormal without the mode, exactly zero
with it. It is large enough that torch splits it across both threads, so a thread without the
mode leaves nonzero entries in its half."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import torch

from sparsesplat.engine.denormals import flush_denormals
from sparsesplat.engine.synthetic import make_scene
from sparsesplat.engine.train import Trainer
from tests.engine.train.loop.test_trainer_parts import small

_PROBE_SIZE = 1 << 20
"""Elements of the probe: far above torch's per-thread grain (32768), so two threads share it."""


def _flushed_fraction() -> float:
    """Fraction of the probe product that came out exactly zero (1.0: every thread flushed)."""
    product = torch.full((_PROBE_SIZE,), 1e-20) * torch.full((_PROBE_SIZE,), 1e-20)
    return float((product == 0).float().mean())


@pytest.fixture
def two_threads() -> Iterator[None]:
    """Run the test with two intra-op threads (restored after)."""
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@pytest.mark.usefixtures("two_threads")
def test_every_thread_flushes_inside_and_the_mode_is_restored_after() -> None:
    # First, outside: the process default keeps denormals (and this starts the second thread
    # before the mode is set; a thread started later would inherit the mode of its creator).
    assert _flushed_fraction() == 0.0
    with flush_denormals():
        assert _flushed_fraction() == 1.0
        with flush_denormals():  # nested: still on after the inner block ends
            assert _flushed_fraction() == 1.0
        assert _flushed_fraction() == 1.0
    assert _flushed_fraction() == 0.0


class _ProbingTrainer(Trainer):
    """Records the probe's flushed fraction at every training step."""

    seen: list[float]

    def _step(self) -> None:
        self.seen.append(_flushed_fraction())
        super()._step()


@pytest.mark.usefixtures("two_threads")
def test_a_cpu_training_run_flushes_denormals_on_its_threads_and_only_while_it_runs() -> None:
    scene, priors = make_scene(seed=0)
    trainer = _ProbingTrainer(scene, small(iterations=4, threads=2), priors)
    trainer.seen = []
    trainer.run()
    assert trainer.seen == [1.0] * 4
    assert _flushed_fraction() == 0.0
