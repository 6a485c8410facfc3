"""The job heartbeat on a real SQLite store: a run that ends between two beats still leaves
its final iteration in the stored progress (a finished job must not read "2 of 40")."""

from __future__ import annotations

import types
from pathlib import Path

from sparsesplat.api.jobs import JobSpec
from sparsesplat.api.settings import Settings
from sparsesplat.api.store.database import make_engine, migrate
from sparsesplat.api.store.jobs import JobStore, new_job_id
from sparsesplat.worker.heartbeat import JobHeartbeat


def test_stop_publishes_the_iteration_reached_after_the_last_beat(tmp_path: Path) -> None:
    engine = make_engine(f"sqlite:///{tmp_path / 'jobs.db'}")
    migrate(engine)
    store = JobStore(engine, max_attempts=2)
    job_id = store.create(new_job_id(), "alice", JobSpec(iterations=40), 3, 1, None)[0].id
    claim = store.claim("w1", lease_s=600)
    assert claim is not None
    # One beat an hour: only the first beat (at start) and the one at stop can happen.
    settings = Settings(data_dir=tmp_path, heartbeat_s=3600, lease_s=7300)
    beat = JobHeartbeat(store, job_id, "w1", settings)
    trainer = types.SimpleNamespace(iteration=2, elapsed_s=0.1, stop_requested=False)
    beat.attach(trainer, 40)
    beat.start()
    trainer.iteration, trainer.elapsed_s = 40, 3.0  # training ends before the next beat
    beat.stop()
    progress = store.get(job_id, "alice").progress  # type: ignore[union-attr]
    assert progress is not None and progress.iteration == 40 and progress.total == 40


def _running(tmp_path: Path) -> tuple[JobStore, str, JobHeartbeat, types.SimpleNamespace]:
    engine = make_engine(f"sqlite:///{tmp_path / 'jobs.db'}")
    migrate(engine)
    store = JobStore(engine, max_attempts=2)
    job_id = store.create(new_job_id(), "alice", JobSpec(iterations=40), 3, 1, None)[0].id
    assert store.claim("w1", lease_s=600) is not None
    beat = JobHeartbeat(
        store, job_id, "w1", Settings(data_dir=tmp_path, heartbeat_s=3600, lease_s=7300)
    )
    trainer = types.SimpleNamespace(
        iteration=2, elapsed_s=0.1, stop_requested=False, discard_outputs=False
    )
    beat.attach(trainer, 40)
    return store, job_id, beat, trainer


def test_a_deleted_job_stops_its_run_without_letting_it_write_files(tmp_path: Path) -> None:
    store, job_id, beat, trainer = _running(tmp_path)
    store.delete(job_id)
    beat._beat()  # the beat that finds the record gone
    assert beat.lost and trainer.stop_requested and trainer.discard_outputs


def test_a_cancelled_job_stops_its_run_and_keeps_its_checkpoint(tmp_path: Path) -> None:
    store, job_id, beat, trainer = _running(tmp_path)
    store.request_cancel(job_id)
    beat._beat()
    assert beat.cancel_requested and trainer.stop_requested and not trainer.discard_outputs
