"""The job repository on a real SQLite database: claims, leases, events, idempotency, pages."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import pytest
import sqlalchemy as sa

from sparsesplat.api.jobs import JobSpec, JobState
from sparsesplat.api.store.database import make_engine, migrate
from sparsesplat.api.store.jobs import JobStore, new_job_id
from sparsesplat.api.store.keys import KeyStore


@pytest.fixture
def store(tmp_path: Path) -> JobStore:
    engine = make_engine(f"sqlite:///{tmp_path / 'jobs.db'}")
    migrate(engine)
    return JobStore(engine, max_attempts=2)


def _submit(store: JobStore, owner: str = "alice", key: str | None = None) -> str:
    job, _ = store.create(new_job_id(), owner, JobSpec(), 3, 1, key)
    return job.id


def test_migrate_twice_is_a_no_op(tmp_path: Path) -> None:
    engine = make_engine(f"sqlite:///{tmp_path / 'jobs.db'}")
    migrate(engine)
    migrate(engine)
    tables = set(sa.inspect(engine).get_table_names())
    assert {"jobs", "events", "api_keys", "workers", "alembic_version"} <= tables


def test_claim_takes_oldest_first_and_only_once(store: JobStore) -> None:
    first, second = _submit(store), _submit(store)
    assert store.get(second, "alice").queue_position == 1  # type: ignore[union-attr]
    claim = store.claim("w1", lease_s=30)
    assert claim is not None and claim.job_id == first and claim.attempt == 1
    assert store.claim("w2", lease_s=30).job_id == second  # type: ignore[union-attr]
    assert store.claim("w3", lease_s=30) is None


def test_concurrent_claims_never_hand_one_job_to_two_workers(store: JobStore) -> None:
    ids = {_submit(store) for _ in range(12)}
    claimed: list[str] = []
    lock = threading.Lock()

    def worker(name: str) -> None:
        while (claim := store.claim(name, lease_s=30)) is not None:
            with lock:
                claimed.append(claim.job_id)

    threads = [threading.Thread(target=worker, args=(f"w{i}",)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(claimed) == sorted(ids)


def test_expired_lease_requeues_then_fails_after_max_attempts(store: JobStore) -> None:
    job = _submit(store)
    assert store.claim("w1", lease_s=0.01) is not None
    time.sleep(0.05)
    again = store.claim("w2", lease_s=0.01)
    assert again is not None and again.job_id == job and again.attempt == 2
    ours, _ = store.heartbeat(job, "w1", 30)
    assert not ours, "the first worker lost the lease"
    time.sleep(0.05)
    assert store.requeue_expired() == [job]
    failed = store.get(job)
    assert failed is not None and failed.state == JobState.failed
    assert "stopped answering 2 times" in (failed.error or "")


def test_events_are_numbered_without_gaps_and_resume_after(store: JobStore) -> None:
    job = _submit(store)
    store.claim("w", 30)
    for i in range(5):
        store.add_event(job, "progress", {"iteration": i})
    seqs = [e.seq for e in store.events_after(job)]
    assert seqs == list(range(1, len(seqs) + 1))
    assert [e.seq for e in store.events_after(job, after=3)] == seqs[3:]


def test_cancel_queued_is_immediate_and_running_is_flagged(store: JobStore) -> None:
    queued, running = _submit(store), _submit(store)
    store.claim("w", 30)  # takes `queued` (oldest)
    cancelled = store.request_cancel(running)
    assert cancelled is not None and cancelled.state == JobState.cancelled
    flagged = store.request_cancel(queued)
    assert flagged is not None and flagged.state == JobState.running
    assert store.request_cancel("job_does_not_exist") is None
    ours, cancel = store.heartbeat(queued, "w", 30)
    assert ours and cancel


def test_idempotency_key_returns_the_first_job_per_owner(store: JobStore) -> None:
    first = _submit(store, key="k1")
    job, created = store.create(new_job_id(), "alice", JobSpec(), 3, 0, "k1")
    assert (job.id, created) == (first, False)
    other, created = store.create(new_job_id(), "bob", JobSpec(), 3, 0, "k1")
    assert created and other.id != first and other.state == JobState.queued


def test_pages_follow_the_cursor_newest_first(store: JobStore) -> None:
    ids = [_submit(store) for _ in range(5)]
    _submit(store, owner="bob")
    seen: list[str] = []
    cursor = None
    while True:
        page, cursor = store.page("alice", cursor=cursor, limit=2)
        seen += [j.id for j in page]
        if cursor is None:
            break
    assert seen == ids[::-1]
    with pytest.raises(ValueError, match="cursor"):
        store.page("alice", cursor="garbage!")


def test_keys_are_stored_hashed_and_revocable(store: JobStore) -> None:
    keys = KeyStore(store.engine)
    info, key = keys.create("ci")
    assert keys.verify(key) == info.id
    with store.engine.begin() as conn:
        stored = conn.execute(sa.text("SELECT digest FROM api_keys")).scalar_one()
    assert key not in stored and len(stored) == 64
    assert keys.revoke(info.id) and keys.verify(key) is None
    assert not keys.revoke(info.id)


def test_a_warning_is_a_field_of_the_job_and_an_event_once(store: JobStore) -> None:
    job_id = _submit(store)
    message = "2 of 2 evaluated views render (nearly) empty. Check the poses"
    seq = store.add_warning(job_id, message)
    assert seq > 0 and store.add_warning(job_id, message) == 0, "the same warning once"
    assert store.get(job_id).warnings == [message]  # type: ignore[union-attr]
    warnings = [e for e in store.events_after(job_id) if e.type == "warning"]
    assert [(e.seq, e.data) for e in warnings] == [(seq, {"message": message})]
    assert store.get(_submit(store)).warnings == []  # type: ignore[union-attr]


def test_a_failed_jobs_message_names_no_server_folder(tmp_path: Path) -> None:
    job = new_job_id()
    from sparsesplat.api.storage import Storage
    from sparsesplat.worker.job_runner import public_message

    storage = Storage(tmp_path / "data")
    upload = storage.upload_dir(job)
    engine_says = f"{upload}/cameras.json: no two cameras see a common region"
    message = public_message(engine_says, storage, job)
    assert message == "cameras.json: no two cameras see a common region"
    assert str(tmp_path) not in public_message(f"{storage.root} is full", storage, job)


def test_a_dead_workers_job_is_requeued_at_once_and_keeps_its_place(store: JobStore) -> None:
    """Worker death seen by its supervisor: the job goes back at once (its lease has not run
    out yet) and, being the oldest, is the next one claimed, ahead of jobs submitted later."""
    from sparsesplat.api.store.workers import WorkerRegistry

    first = _submit(store)
    claim = store.claim("train-dead", lease_s=600)
    assert claim is not None and claim.job_id == first
    later = [_submit(store) for _ in range(3)]
    registry = WorkerRegistry(store.engine)
    registry.register("train-dead", "train")
    dead = registry.ids_of_process(os.getpid())
    assert dead == ["train-dead"]
    assert store.requeue_expired() == [], "the lease is still valid"
    assert store.requeue_of_workers(dead) == [first]
    job = store.get(first)
    assert job is not None and job.state == JobState.queued and job.queue_position == 0
    assert store.get(later[0]).queue_position == 1  # type: ignore[union-attr]
    again = store.claim("train-new", lease_s=600)
    assert again is not None and (again.job_id, again.attempt) == (first, 2)


def test_the_supervisor_reports_a_dead_worker_before_replacing_it() -> None:
    import subprocess
    import sys

    from sparsesplat.worker.supervisor import Supervisor, _Slot

    seen: list[tuple[str, int]] = []
    supervisor = Supervisor(0, 0, on_exit=lambda kind, pid: seen.append((kind, pid)))
    slot = _Slot("train", subprocess.Popen([sys.executable, "-c", "pass"]), time.monotonic())
    assert slot.process is not None
    pid = slot.process.pid
    slot.process.wait()
    supervisor._tend(slot, time.monotonic())
    assert seen == [("train", pid)]
    assert slot.process is None, "replaced only after the back-off"
