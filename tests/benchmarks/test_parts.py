"""bench-parts: each variant builds the LLFF recipe with exactly its part switched on, past
every schedule start, with the model size held fixed while it is timed."""

from __future__ import annotations

import pytest

from benchmarks.parts import DEFAULT_VARIANTS, build, time_round

PART_ATTRIBUTES = {
    "set:dropout=true": "dropout",
    "set:dtu_background=true": "dtu",
    "set:consistency_weight=0.1": "consistency",
    "set:near_prune=true": "near_prune",
}


@pytest.mark.parametrize("variant", [v for v in DEFAULT_VARIANTS if v != "set:init=dense"])
def test_a_variant_switches_on_its_part_only(variant: str) -> None:
    trainer, setup = build(variant, gaussians=300, size=(96, 72))
    assert setup > 0
    for v, attribute in PART_ATTRIBUTES.items():
        assert (getattr(trainer, attribute) is not None) == (v == variant), attribute
    n = len(trainer.gaussians)
    start = trainer.iteration
    assert time_round(trainer, 2) > 0
    assert trainer.iteration == start + 2
    assert len(trainer.gaussians) == n  # densification off: every round times the same model
