"""Storage life on a real SQLite database and real files: pins, expiry, usage counts, the wait
for disk space, and telling a full disk from other errors."""

from __future__ import annotations

import errno
import sqlite3
import time
from pathlib import Path

import pytest
import sqlalchemy as sa

from sparsesplat.api.disk import disk_full_message, is_disk_full, remove_partial_files, tree_bytes
from sparsesplat.api.jobs import JobSpec, JobState
from sparsesplat.api.store.database import make_engine, migrate
from sparsesplat.api.store.jobs import JobStore, new_job_id


@pytest.fixture
def store(tmp_path: Path) -> JobStore:
    engine = make_engine(f"sqlite:///{tmp_path / 'jobs.db'}")
    migrate(engine)
    # 3 s: the "not expired yet" check right after a model is made must not lose a race with a
    # stalled, loaded machine (0.5 s could); the expiry test then sleeps to the expiry time.
    return JobStore(engine, max_attempts=2, model_ttl_s=3.0)


def _succeeded(store: JobStore, owner: str = "alice") -> str:
    job_id = store.create(new_job_id(), owner, JobSpec(), 3, 1)[0].id
    claim = store.claim_job(job_id, "w1", lease_s=30)
    assert claim is not None
    assert store.finish(job_id, "w1", JobState.succeeded, "trained")
    return job_id


def test_an_unpinned_model_expires_and_a_pinned_one_stays(store: JobStore) -> None:
    kept, goes = _succeeded(store), _succeeded(store)
    assert store.set_pinned(kept, True)
    job = store.get(goes)
    assert job is not None and job.has_model and job.expires_at is not None and not job.expired
    assert store.expired_unswept() == []
    time.sleep(max(0.0, job.expires_at.timestamp() - time.time()) + 0.1)
    assert store.get(goes).expired and not store.get(goes).has_model  # type: ignore[union-attr]
    pinned = store.get(kept)
    assert pinned is not None and pinned.has_model and pinned.expires_at is None
    assert store.expired_unswept() == [goes]
    assert store.mark_expired(goes) and not store.mark_expired(goes)
    assert not store.mark_expired(kept)
    assert store.counts_of_owner("alice") == {"jobs": 2, "active": 0, "models": 1, "pinned": 1}


def test_no_expiry_when_the_setting_is_zero(tmp_path: Path) -> None:
    engine = make_engine(f"sqlite:///{tmp_path / 'jobs.db'}")
    migrate(engine)
    store = JobStore(engine)
    job_id = _succeeded(store)
    job = store.get(job_id)
    assert job is not None and job.expires_at is None and not job.expired
    assert store.expired_unswept() == [] and not store.mark_expired(job_id)


def test_a_job_waiting_for_disk_space_is_noted_once_then_fails(store: JobStore) -> None:
    job_id = store.create(new_job_id(), "alice", JobSpec(), 3, 1)[0].id
    head = store.oldest_queued()
    assert head is not None and head[0] == job_id and head[2] is None
    since = store.note_disk_wait(job_id, "waiting for disk space: needs ~44 MB")
    assert since is not None and store.note_disk_wait(job_id, "again") == since
    job = store.get(job_id)
    assert job is not None and job.state == JobState.queued
    assert job.warnings == ["waiting for disk space: needs ~44 MB"]
    assert store.fail_queued(job_id, "no space left on device to start this job")
    assert not store.fail_queued(job_id, "twice")
    failed = store.get(job_id)
    assert failed is not None and failed.state == JobState.failed
    assert failed.error == "no space left on device to start this job"
    assert store.oldest_queued() is None


def test_a_claim_clears_the_wait(store: JobStore) -> None:
    job_id = store.create(new_job_id(), "alice", JobSpec(), 3, 1)[0].id
    store.note_disk_wait(job_id, "waiting")
    assert store.claim_job(job_id, "w1", 30) is not None
    store.release(job_id, "w1", "back")
    assert store.spec_of_queued(job_id) == (JobSpec().model_dump(mode="json"), None)


def test_full_disk_errors_are_told_from_others() -> None:
    assert is_disk_full(OSError(errno.ENOSPC, "No space left on device"))
    assert is_disk_full(OSError(errno.EDQUOT, "Disk quota exceeded"))
    assert not is_disk_full(OSError(errno.ENOENT, "No such file"))
    full_db = sa.exc.OperationalError(
        "INSERT", {}, sqlite3.OperationalError("database or disk is full")
    )
    assert is_disk_full(full_db)
    pg_full = sa.exc.OperationalError(
        "INSERT", {}, RuntimeError('could not extend file "base/1/2": No space left on device')
    )
    assert is_disk_full(pg_full)
    locked = sa.exc.OperationalError("INSERT", {}, sqlite3.OperationalError("database is locked"))
    assert not is_disk_full(locked)
    # torch.save says only that its write failed: a full disk when the space is not there.
    torch_error = RuntimeError(
        "[enforce fail at inline_container.cc:672] . unexpected pos 704 vs 598"
    )
    assert is_disk_full(torch_error, free=4096, needed=44_000_000)
    assert not is_disk_full(torch_error, free=10**10, needed=44_000_000)
    wrapped = RuntimeError("saving failed")
    wrapped.__cause__ = OSError(errno.ENOSPC, "No space left on device")
    assert is_disk_full(wrapped)
    message = disk_full_message("writing the training checkpoint", 44_000_000, 3_200_000)
    assert message == (
        "no space left on device while writing the training checkpoint (needs ~44 MB, 3.2 MB free)"
    )


def test_partial_files_go_and_bytes_are_the_files(tmp_path: Path) -> None:
    run = tmp_path / "job" / "run"
    run.mkdir(parents=True)
    (run / "checkpoint.pt.tmp").write_bytes(b"x" * 100)
    (run / "priors").mkdir()
    (run / "priors" / "prior_a.npz.tmp.npz").write_bytes(b"x" * 10)
    (run / "checkpoint.pt").write_bytes(b"x" * 1000)
    (tmp_path / "job" / "cameras.json").write_bytes(b"{}")
    assert tree_bytes(tmp_path / "job") == 1112
    removed = sorted(p.name for p in remove_partial_files(tmp_path / "job"))
    assert removed == ["checkpoint.pt.tmp", "prior_a.npz.tmp.npz"]
    assert tree_bytes(tmp_path / "job") == 1002
    assert tree_bytes(tmp_path / "absent") == 0


def test_reports_of_a_deleted_job_go_nowhere(store: JobStore) -> None:
    job_id = store.create(new_job_id(), "alice", JobSpec(), 3, 1)[0].id
    assert store.claim_job(job_id, "w1", 30) is not None
    store.delete(job_id)
    assert store.add_event(job_id, "record", {"iteration": 1}) == 0
    assert store.add_warning(job_id, "late") == 0
    assert store.heartbeat(job_id, "w1", 30) == (False, False)
    assert store.events_after(job_id) == []


def test_the_sweep_removes_expired_models_and_stray_folders_only(tmp_path: Path) -> None:
    import os

    from sparsesplat.api.settings import Settings
    from sparsesplat.server.expiry import STRAY_AGE_S, sweep
    from sparsesplat.server.state import ServiceState

    settings = Settings(data_dir=tmp_path / "data", model_ttl_days=0.4 / 86400)
    service = ServiceState.open(settings)
    try:
        expired, pinned = _succeeded(service.jobs), _succeeded(service.jobs)
        service.jobs.set_pinned(pinned, True)
        stray_old, stray_new = new_job_id(), new_job_id()
        for job_id in (expired, pinned, stray_old, stray_new):
            (service.storage.run_dir(job_id)).mkdir(parents=True)
            (service.storage.run_dir(job_id) / "checkpoint.pt").write_bytes(b"x" * 10)
        old = time.time() - STRAY_AGE_S - 60
        os.utime(service.storage.job_dir(stray_old), (old, old))
        time.sleep(0.5)
        assert sorted(sweep(service)) == sorted([expired, stray_old])
        on_disk = set(service.storage.job_ids_on_disk())
        assert on_disk == {pinned, stray_new}, "pinned models and young folders stay"
        job = service.jobs.get(expired)
        assert job is not None and job.expired and not job.has_model
        assert sweep(service) == []
    finally:
        service.engine.dispose()
