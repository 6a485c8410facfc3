"""The disk budget's figures against real runs: the bytes per Gaussian and of the neural colour
field that ``docs/service.md`` states are what the trainer writes, and a job's expected bytes
cover what it holds at its peak."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from sparsesplat.api.jobs import JobSpec
from sparsesplat.worker.disk_budget import (
    EXPORT_BYTES_PER_GAUSSIAN,
    checkpoint_bytes,
    expected_job_bytes,
    model_bytes,
)

pytestmark = pytest.mark.shared_data


@pytest.mark.parametrize("color", ["sh", "neural"])
def test_checkpoint_model_and_export_sizes_follow_the_figures(
    color: str, mic_upload: Path, tmp_path: Path
) -> None:
    from sparsesplat.engine.datasets import load_scene
    from sparsesplat.engine.train.checkpoint import load_checkpoint, model_state
    from sparsesplat.engine.train.run import RunSpec, build_run

    overrides = {"depth.prior": "none", "color.model": color, "threads": 1,
                 "init.points": 3000, "record.eval_interval_s": 1e9}  # fmt: skip
    run_dir = tmp_path / "run"
    run = build_run(RunSpec(None, overrides, 5, None), load_scene(mic_upload, format="folder"),
                    out_dir=run_dir)  # fmt: skip
    run.trainer.run()
    n = len(run.trainer.gaussians)
    checkpoint = (run_dir / "checkpoint.pt").stat().st_size
    assert checkpoint == pytest.approx(checkpoint_bytes(color, n), rel=0.005, abs=40_000)
    torch.save(model_state(load_checkpoint(run_dir / "checkpoint.pt")), tmp_path / "model.pt")
    model = (tmp_path / "model.pt").stat().st_size
    assert model == pytest.approx(model_bytes(color, n), rel=0.005, abs=40_000)
    exports = sum((run_dir / name).stat().st_size for name in ("model.ply", "model.splat"))
    assert exports == pytest.approx(EXPORT_BYTES_PER_GAUSSIAN * n, abs=5_000)


def test_expected_bytes_cover_a_job_at_its_peak(mic_upload: Path) -> None:
    sh = expected_job_bytes(JobSpec(iterations=30, depth_prior="none", color_model="sh"),
                            mic_upload)  # fmt: skip
    # mic's preset starts from 10k Gaussians; 30 iterations hold no densification step.
    assert 2 * checkpoint_bytes("sh", 10_000) <= sh <= 2 * checkpoint_bytes("sh", 10_000) + 3e6
    neural = expected_job_bytes(JobSpec(iterations=60, depth_prior="none"), mic_upload)
    assert neural >= 2 * checkpoint_bytes("neural", 10_000) > 290e6
    longer = expected_job_bytes(JobSpec(iterations=6000, depth_prior="none"), mic_upload)
    assert longer > neural, "densification steps raise the expected Gaussians"
