"""Storing a running job's files in the remote artifact store as they change.

With ``SPARSESPLAT_ARTIFACTS=s3://...`` the bucket, not this machine, holds the job: each new
checkpoint is stored as soon as the trainer has renamed it into place (an object appears only
once complete, so a reader sees the previous checkpoint or the new one, never a part), and a
worker on any machine resumes from it after this one died. Only what resume and the server
need is sent: the checkpoint, the metrics series (the plot the page shows) and the depth-prior
pictures; the prior cache and partial files stay here. Without a remote store this does
nothing.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from pathlib import Path

from sparsesplat.api.artifacts import ArtifactStoreError
from sparsesplat.api.disk import is_partial
from sparsesplat.api.storage import Storage

log = logging.getLogger("sparsesplat.worker")

SYNC_INTERVAL_S = 0.5
"""Seconds between looks at the run folder: a checkpoint is stored at most this late."""


def kept_for_good(storage: Storage, job_id: str) -> Callable[[Path], bool]:
    """Which of the run folder's files the store keeps: all but partial files and the depth
    prior cache (the prior pictures, ``priors/view_*.png``, are kept)."""
    priors = storage.prior_picture(job_id, 0).parent

    def keep(path: Path) -> bool:
        if is_partial(path):
            return False
        return path.parent != priors or path.name.startswith("view_")

    return keep


class RunSync:
    """A thread storing the run folder's changed files while the job trains."""

    def __init__(
        self, storage: Storage, job_id: str, allowed: Callable[[], bool] = lambda: True
    ) -> None:
        """Sync ``job_id``'s run folder while ``allowed()`` (False once the lease is lost:
        the job is another worker's then, and an older checkpoint must not replace its
        newer one)."""
        self.storage = storage
        self.job_id = job_id
        self.allowed = allowed
        self.error: ArtifactStoreError | None = None
        """The last failure to store (the final :meth:`push_changed` raises it again)."""
        self._keep = kept_for_good(storage, job_id)
        self._sent: dict[Path, tuple[int, int]] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Begin watching (nothing happens without a remote store)."""
        if self.storage.remote is None:
            return
        self._thread = threading.Thread(target=self._loop, name="artifact-sync", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop watching (waits for a store in progress to end)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    def push_changed(self) -> int:
        """Store every kept file that changed since it was last stored; returns how many.
        Raises ``ArtifactStoreError`` when the store refuses."""
        if self.storage.remote is None or not self.allowed():
            return 0
        run_dir = self.storage.run_dir(self.job_id)
        sent = 0
        # The checkpoint first: it is what a resume needs.
        for path in sorted(run_dir.rglob("*"), key=lambda p: p.name != "checkpoint.pt"):
            try:
                stat = path.stat()
            except FileNotFoundError:  # replaced or removed meanwhile: the next look sees it
                continue
            if not path.is_file() or not self._keep(path):
                continue
            seen = (stat.st_mtime_ns, stat.st_size)
            if self._sent.get(path) == seen:
                continue
            try:
                self.storage.publish(path)
            except FileNotFoundError:
                continue
            self._sent[path] = seen
            sent += 1
        return sent

    def _loop(self) -> None:
        while not self._stop.wait(SYNC_INTERVAL_S):
            try:
                self.push_changed()
                self.error = None
            except ArtifactStoreError as exc:
                # Training goes on (the store may come back); the final store raises again.
                if self.error is None:
                    log.error("cannot store the job's files", extra={"error": str(exc)})
                self.error = exc
