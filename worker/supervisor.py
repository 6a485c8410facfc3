"""Keeps a set of worker processes running: N training workers and M render workers.

Each worker is a fresh interpreter (``python -m sparsesplat.worker train|render``), so a crash,
an out-of-memory kill or a hard stop after a cancel takes only that process; the supervisor
starts a replacement (after a short back-off if it keeps dying). SIGTERM/SIGINT are passed on,
and the supervisor waits for its children to finish gracefully.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from types import FrameType

log = logging.getLogger("sparsesplat.supervisor")

RESTART_BACKOFF_S = (0.5, 2.0, 5.0, 15.0)
"""Delays before restarting a worker that died again soon after starting."""
STABLE_AFTER_S = 60.0
"""A worker that ran this long resets its back-off."""
STOP_TIMEOUT_S = 60.0
"""How long children get to stop gracefully before they are killed."""


def worker_environment() -> dict[str, str]:
    """The environment of a worker process: ours, with OpenMP threads that sleep when idle.

    Training and render workers share the cores. With OpenMP's default (spin-waiting) policy an
    idle team keeps spinning on the cores the other process needs; measured on the rasterizer,
    OpenMP stages collapse 5-15x under such contention. PASSIVE makes waiting threads sleep.
    A value set by the operator wins.
    """
    env = dict(os.environ)
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    return env


@dataclass
class _Slot:
    kind: str
    process: subprocess.Popen[bytes] | None = None
    started: float = 0.0
    failures: int = 0
    next_start: float = 0.0
    history: list[int] = field(default_factory=list)


class Supervisor:
    """Starts and restarts worker processes until stopped."""

    def __init__(
        self, train: int, render: int, on_exit: Callable[[str, int], None] | None = None
    ) -> None:
        """``train`` training workers and ``render`` render workers; ``on_exit(kind, pid)``
        runs when a worker process has exited, before it is replaced."""
        self.slots = [_Slot("train") for _ in range(train)] + [
            _Slot("render") for _ in range(render)
        ]
        self.on_exit = on_exit
        self._stopping = False

    def run(self) -> int:
        """Supervise until SIGTERM/SIGINT; returns 0."""
        signal.signal(signal.SIGTERM, self._on_signal)
        signal.signal(signal.SIGINT, self._on_signal)
        parent = os.getppid()
        while not self._stopping:
            if os.getppid() != parent:  # whoever started us is gone: do not linger as orphans
                log.warning("parent process gone; stopping the workers")
                break
            now = time.monotonic()
            for slot in self.slots:
                self._tend(slot, now)
            time.sleep(0.2)
        self._stop_all()
        return 0

    def _tend(self, slot: _Slot, now: float) -> None:
        if slot.process is not None:
            code = slot.process.poll()
            if code is None:
                return
            slot.history.append(code)
            lived = now - slot.started
            slot.failures = 0 if lived > STABLE_AFTER_S else slot.failures + 1
            delay = RESTART_BACKOFF_S[min(slot.failures, len(RESTART_BACKOFF_S) - 1)]
            slot.next_start = now + delay
            log.warning("worker exited; restarting",
                        extra={"kind": slot.kind, "code": code, "restart_in_s": delay})  # fmt: skip
            if self.on_exit is not None:
                try:
                    self.on_exit(slot.kind, slot.process.pid)
                except Exception:  # a cleanup that failed must not stop the supervision
                    log.warning("handling a worker's exit failed", exc_info=True)
            slot.process = None
        if now >= slot.next_start:
            slot.process = subprocess.Popen(
                [sys.executable, "-m", "sparsesplat.worker", slot.kind], env=worker_environment()
            )
            slot.started = now

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        self._stopping = True

    def _stop_all(self) -> None:
        running = [s.process for s in self.slots if s.process is not None]
        for process in running:
            process.terminate()
        deadline = time.monotonic() + STOP_TIMEOUT_S
        for process in running:
            try:
                process.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                process.kill()


def requeue_jobs_of_dead_workers(
    database_url: str, max_attempts: int
) -> Callable[[str, int], None]:
    """An ``on_exit`` for :class:`Supervisor`: the job a dead training worker held goes back to
    the queue at once (not when its lease expires), so it resumes before later jobs."""
    from sparsesplat.api.store.database import make_engine
    from sparsesplat.api.store.jobs import JobStore
    from sparsesplat.api.store.workers import WorkerRegistry

    engine = make_engine(database_url)
    store, registry = JobStore(engine, max_attempts), WorkerRegistry(engine)

    def on_exit(kind: str, pid: int) -> None:
        if kind != "train":
            return
        dead = registry.ids_of_process(pid)
        requeued = store.requeue_of_workers(dead)
        for worker_id in dead:
            registry.unregister(worker_id)
        if requeued:
            log.warning("re-queued the job(s) of a dead worker", extra={"jobs": requeued})

    return on_exit
