"""The one migration history and the job store on a real PostgreSQL: migrations run (and run
concurrently), claims of one job race safely, duplicate deliveries are dropped."""

from __future__ import annotations

import threading
import time
import uuid

import sqlalchemy as sa

from sparsesplat.api.jobs import JobSpec, JobState
from sparsesplat.api.store.database import make_engine, migrate
from sparsesplat.api.store.jobs import JobStore, new_job_id
from tests.distributed.servers import PostgresServer


def _fresh(postgres: PostgresServer) -> sa.Engine:
    return make_engine(postgres.create_database(f"store_{uuid.uuid4().hex[:8]}"))


def test_the_sqlite_migration_history_runs_on_postgresql_concurrently(
    postgres: PostgresServer,
) -> None:
    engine = _fresh(postgres)
    errors: list[BaseException] = []

    def run() -> None:
        try:
            migrate(make_engine(engine.url.render_as_string(hide_password=False)))
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=run) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    migrate(engine)  # and again: nothing to do
    with engine.begin() as conn:
        head = conn.execute(sa.text("SELECT version_num FROM alembic_version")).scalars().all()
        tables = set(sa.inspect(conn).get_table_names())
    from alembic.script import ScriptDirectory

    from sparsesplat.api.store.database import MIGRATIONS

    assert head == [ScriptDirectory(str(MIGRATIONS)).get_current_head()]
    assert {"jobs", "events", "api_keys", "workers"} <= tables
    engine.dispose()


def test_claim_job_takes_a_queued_job_once_and_drops_late_messages(
    postgres: PostgresServer,
) -> None:
    engine = _fresh(postgres)
    migrate(engine)
    store = JobStore(engine, max_attempts=2)
    job, created = store.create(new_job_id(), "anon", JobSpec(iterations=10), 3, 0)
    job_id = job.id
    assert created and job.state == JobState.queued

    # Eight deliveries of one message race: exactly one claims the job.
    claims: list[object] = []
    barrier = threading.Barrier(8)

    def deliver(i: int) -> None:
        barrier.wait()
        claims.append(store.claim_job(job_id, f"w{i}", lease_s=30))

    threads = [threading.Thread(target=deliver, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    won = [c for c in claims if c is not None]
    assert len(won) == 1 and won[0].attempt == 1  # type: ignore[attr-defined]
    holder = store.get(job_id)
    assert holder is not None and holder.state == JobState.running

    # A message for a running, a finished, a cancelled or a deleted job is dropped.
    assert store.claim_job(job_id, "late", lease_s=30) is None
    with engine.begin() as conn:
        holder_id = conn.execute(sa.text("SELECT worker_id FROM jobs WHERE id=:j"),
                                 {"j": job_id}).scalar_one()  # fmt: skip
    assert store.finish(job_id, holder_id, JobState.succeeded, "done")
    assert store.claim_job(job_id, "late", lease_s=30) is None
    cancelled = store.create(new_job_id(), "anon", JobSpec(iterations=10), 3, 0)[0].id
    store.request_cancel(cancelled)
    assert store.claim_job(cancelled, "late", lease_s=30) is None
    assert store.claim_job("job_does_not_exist", "late", lease_s=30) is None

    # A lease that ran out: re-queued, claimed again as attempt 2 (then failed at the limit).
    again = store.create(new_job_id(), "anon", JobSpec(iterations=10), 3, 0)[0].id
    assert store.claim_job(again, "dies", lease_s=0.05) is not None
    time.sleep(0.1)
    assert store.requeue_expired() == [again]
    second = store.claim_job(again, "next", lease_s=0.05)
    assert second is not None and second.attempt == 2
    time.sleep(0.1)
    assert store.requeue_expired() == [again]
    job = store.get(again)
    assert job is not None and job.state == JobState.failed and "2 times" in (job.error or "")

    states = [e.data["state"] for e in store.events_after(again) if e.type == "state"]
    assert states == ["queued", "running", "queued", "running", "failed"]
    seqs = [e.seq for e in store.events_after(again)]
    assert seqs == list(range(1, len(seqs) + 1))
    engine.dispose()
