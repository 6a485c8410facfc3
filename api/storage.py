"""Where a job's files live: one storage interface over a directory tree.

    <root>/jobs/<job_id>/upload/   cameras.json (our names), images/, depth/   (written once)
                                   photos without cameras: photos.json + images/ first, then
                                   cameras.json + sparse_points.npz once estimated
    <root>/jobs/<job_id>/run/      checkpoint.pt, model.ply, model.splat, metrics*.{json,csv,png}
    <root>/staging/                uploads being received (moved into place in one rename)

File names sent by clients never become paths: uploads are stored under names we choose.
The root may be a shared mount (NFS) for workers on several machines, or each machine's own
folder when a remote artifact store (``SPARSESPLAT_ARTIFACTS=s3://...``, see
``sparsesplat.api.artifacts``) keeps the files: the same tree, object by object, under the
same names. Then the server stores a committed upload there; a worker fetches the upload and
the latest checkpoint, and stores each new checkpoint and the final files; the server and the
render workers fetch what they serve. The ``publish_*`` / ``fetch*`` methods do nothing more
than local file checks without a remote store.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from sparsesplat.api.artifacts import (
    ArtifactMissing,
    ArtifactStoreError,
    RemoteArtifacts,
    open_remote,
)
from sparsesplat.api.artifacts.mirror import Mirror
from sparsesplat.api.disk import tree_bytes
from sparsesplat.api.names import ARTIFACT_FILES

if TYPE_CHECKING:
    from sparsesplat.api.settings import Settings

_JOB_ID = re.compile(r"^job_[0-9a-f]{20}$")

PHOTOS_FILE = "photos.json"
"""The manifest of an upload of photos without cameras (stored images, the names they were
uploaded under, optional shared intrinsics); the worker estimates cameras.json from it."""


class StorageError(ValueError):
    """A path asked of the storage is not one it hands out."""


class Storage:
    """Files of every job under one root directory, kept in a remote store when one is set."""

    def __init__(self, root: str | Path, remote: RemoteArtifacts | None = None) -> None:
        """Storage rooted at ``root`` (created when missing), mirrored into ``remote``."""
        self.root = Path(root)
        (self.root / "jobs").mkdir(parents=True, exist_ok=True)
        (self.root / "staging").mkdir(parents=True, exist_ok=True)
        self.remote = remote
        self._mirror = Mirror(self.root, remote) if remote is not None else None

    @classmethod
    def for_settings(cls, settings: Settings) -> Storage:
        """The storage ``settings`` name: ``data_dir``, and the ``artifacts`` store if set."""
        return cls(settings.data_dir, open_remote(settings))

    def check(self) -> None:
        """Raise ``ArtifactStoreError`` naming the cause when the remote store (if any)
        cannot be used (unreachable, no bucket, refused credentials)."""
        if self.remote is not None:
            self.remote.check()

    def job_dir(self, job_id: str) -> Path:
        """The job's folder (raises StorageError for anything that is not a job id)."""
        if not _JOB_ID.match(job_id):
            raise StorageError(f"not a job id: {job_id!r}")
        return self.root / "jobs" / job_id

    def upload_dir(self, job_id: str) -> Path:
        """The scene as uploaded (folder format: cameras.json + images)."""
        return self.job_dir(job_id) / "upload"

    def run_dir(self, job_id: str) -> Path:
        """Where the trainer writes checkpoints, exports and metrics."""
        return self.job_dir(job_id) / "run"

    def artifact(self, job_id: str, kind: str) -> Path:
        """Path of one artifact kind (see :data:`~sparsesplat.api.names.ARTIFACT_FILES`); it
        may not exist yet."""
        if kind not in ARTIFACT_FILES:
            raise StorageError(f"unknown artifact {kind!r}; one of {', '.join(ARTIFACT_FILES)}")
        return self.run_dir(job_id) / ARTIFACT_FILES[kind]

    def prior_picture(self, job_id: str, index: int) -> Path:
        """The ``index``-th training view's depth prior drawn as an 8-bit PNG (near = bright)."""
        return self.run_dir(job_id) / "priors" / f"view_{index:03d}.png"

    def new_staging_dir(self) -> Path:
        """An empty folder to receive an upload into; commit or discard it."""
        path = self.root / "staging" / uuid.uuid4().hex
        path.mkdir()
        return path

    def commit_upload(self, staging: Path, job_id: str) -> Path:
        """Move a complete staged upload into place in one rename, and store it in the remote
        store (if any); returns the upload dir. When storing fails nothing of it is kept."""
        target = self.upload_dir(job_id)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(staging, target)
        try:
            self.publish_upload(job_id)
        except BaseException:
            shutil.rmtree(self.job_dir(job_id), ignore_errors=True)
            with contextlib.suppress(ArtifactStoreError):  # the store's own failure wins
                if self._mirror is not None:
                    self._mirror.delete_tree(self.job_dir(job_id))
            raise
        return target

    def publish_upload(self, job_id: str) -> None:
        """Store the upload's files the remote store lacks (cameras estimated by the worker
        join the photos there)."""
        if self._mirror is not None:
            self._mirror.push_tree(self.upload_dir(job_id))

    def fetch_upload(self, job_id: str) -> None:
        """Make the upload complete here (a worker on another machine than the server);
        ``ArtifactMissing`` when the remote store has none."""
        if self._mirror is not None:
            self._mirror.pull_tree(self.upload_dir(job_id))

    def fetch_checkpoint(self, job_id: str) -> bool:
        """Bring the stored training checkpoint here, over any local one (the store has the
        latest: another worker may have trained the job further since this machine ran it);
        False when none is stored (a local one, if any, stays)."""
        if self._mirror is None:
            return False
        try:
            self._mirror.pull(self.artifact(job_id, "checkpoint"), fresh=True)
        except ArtifactMissing:
            return False
        return True

    def publish(self, path: Path) -> None:
        """Store one file of a job's folder (a new checkpoint, a final export)."""
        if self._mirror is not None:
            self._mirror.push(path)

    def publish_run(self, job_id: str, include: Callable[[Path], bool] = lambda _: True) -> None:
        """Store the run folder's files (that ``include`` keeps) the store lacks or holds at
        another size."""
        if self._mirror is not None:
            self._mirror.push_tree(self.run_dir(job_id), include)

    def fetch(self, path: Path, fresh: bool = False) -> Path:
        """A local copy of a job's file ``path`` (from :meth:`artifact`, :meth:`upload_dir`,
        ...): the one here, or the stored one (``fresh``: the stored one even when a copy is
        here, for files that change while a job runs); ``ArtifactMissing`` when there is
        none."""
        if self._mirror is not None:
            return self._mirror.pull(path, fresh)
        if not path.is_file():
            raise ArtifactMissing(f"no file {path.name}")
        return path

    def has(self, path: Path) -> bool:
        """Whether a job's file ``path`` exists here or in the remote store."""
        return self._mirror.exists(path) if self._mirror is not None else path.is_file()

    def job_bytes(self, job_id: str) -> int:
        """Bytes the job's files hold (in the remote store when there is one)."""
        if self._mirror is not None:
            return self._mirror.stored_bytes(self.job_dir(job_id))
        return tree_bytes(self.job_dir(job_id))

    @staticmethod
    def discard(staging: Path) -> None:
        """Remove a staged upload that will not become a job."""
        shutil.rmtree(staging, ignore_errors=True)

    def delete_job(self, job_id: str) -> None:
        """Remove every file of a job (here, and in the remote store)."""
        shutil.rmtree(self.job_dir(job_id), ignore_errors=True)
        if self._mirror is not None:
            self._mirror.delete_tree(self.job_dir(job_id))

    def job_ids_on_disk(self) -> list[str]:
        """Job folders present (for finding files whose job record is gone)."""
        return sorted(p.name for p in (self.root / "jobs").iterdir() if _JOB_ID.match(p.name))

    def stored_jobs(self) -> dict[str, float]:
        """Every job with files here or in the remote store → when they last changed (Unix
        seconds: the folder's time here, the newest object's in the store; the later one),
        for finding files whose job record is gone."""
        out: dict[str, float] = {}
        for job_id in self.job_ids_on_disk():
            with contextlib.suppress(OSError):  # removed meanwhile
                out[job_id] = self.job_dir(job_id).stat().st_mtime
        if self._mirror is not None:
            for job_id, stored_at in self._mirror.newest(self.root / "jobs").items():
                if _JOB_ID.match(job_id):
                    out[job_id] = max(out.get(job_id, 0.0), stored_at)
        return out
