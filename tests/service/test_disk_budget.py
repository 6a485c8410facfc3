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
    from sparsesplat.engine.model.checkpoint import load_checkpoint, model_state
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
    neural = expected_job_bytes(
        JobSpec(iterations=60, depth_prior="none", color_model="neural"), mic_upload
    )
    assert neural >= 2 * checkpoint_bytes("neural", 10_000) > 290e6
    longer = expected_job_bytes(
        JobSpec(iterations=6000, depth_prior="none", color_model="neural"), mic_upload
    )
    assert longer > neural, "densification steps raise the expected Gaussians"


def test_the_gate_counts_running_jobs_growth_and_what_a_resumed_job_holds(
    mic_upload: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import shutil

    from sparsesplat.api.faults import FAULTS_ENV
    from sparsesplat.api.settings import Settings
    from sparsesplat.api.storage import Storage
    from sparsesplat.api.store.database import make_engine, migrate
    from sparsesplat.api.store.jobs import JobStore, new_job_id
    from sparsesplat.worker.disk_guard import DiskGate

    rules = tmp_path / "faults"
    monkeypatch.setenv(FAULTS_ENV, str(rules))
    settings = Settings(data_dir=tmp_path / "data", disk_reserve_mb=1)
    engine = make_engine(settings.database_url or "")
    migrate(engine)
    store, storage = JobStore(engine), Storage(settings.data_dir)
    spec = JobSpec(iterations=30, depth_prior="none", color_model="sh")
    running, queued = new_job_id(), new_job_id()
    for job_id in (running, queued):
        shutil.copytree(mic_upload, storage.upload_dir(job_id))
        store.create(job_id, "alice", spec, 3, 2)
    gate = DiskGate(store, storage, settings)
    one_job = gate.expected_bytes(queued, spec.model_dump(mode="json"))
    rules.write_text(f"free {int(1.5 * one_job)}\n")

    head = store.oldest_queued()
    assert head is not None and head[0] == running
    assert gate.may_start(*head), "one job fits in 1.5 jobs' room"
    assert store.claim_job(running, "w1", 30) is not None
    head = store.oldest_queued()
    assert head is not None and head[0] == queued
    assert not gate.may_start(*head), "the running job will still grow into that room"
    job = store.get(queued)
    assert job is not None and job.warnings[0].startswith("waiting for disk space")

    # The running job has written most of what it will: the rest fits.
    run = storage.run_dir(running)
    run.mkdir(parents=True)
    (run / "checkpoint.pt").write_bytes(b"\0" * int(0.8 * one_job))
    head = store.oldest_queued()
    assert head is not None and gate.may_start(*head)
    engine.dispose()
