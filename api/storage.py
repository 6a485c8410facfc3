"""Where a job's files live: one storage interface over a directory tree.

    <root>/jobs/<job_id>/upload/   cameras.json (our names), images/, depth/   (written once)
                                   photos without cameras: photos.json + images/ first, then
                                   cameras.json + sparse_points.npz once estimated
    <root>/jobs/<job_id>/run/      checkpoint.pt, model.ply, model.splat, metrics*.{json,csv,png}
    <root>/staging/                uploads being received (moved into place in one rename)

File names sent by clients never become paths: uploads are stored under names we choose.
The root may be a shared mount (NFS) for workers on several machines.
"""

from __future__ import annotations

import os
import re
import shutil
import uuid
from pathlib import Path

from sparsesplat.api.names import ARTIFACT_FILES

_JOB_ID = re.compile(r"^job_[0-9a-f]{20}$")

PHOTOS_FILE = "photos.json"
"""The manifest of an upload of photos without cameras (stored images, the names they were
uploaded under, optional shared intrinsics); the worker estimates cameras.json from it."""


class StorageError(ValueError):
    """A path asked of the storage is not one it hands out."""


class Storage:
    """Files of every job under one root directory."""

    def __init__(self, root: str | Path) -> None:
        """Storage rooted at ``root`` (created when missing)."""
        self.root = Path(root)
        (self.root / "jobs").mkdir(parents=True, exist_ok=True)
        (self.root / "staging").mkdir(parents=True, exist_ok=True)

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
        """Move a complete staged upload into place in one rename; returns the upload dir."""
        target = self.upload_dir(job_id)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(staging, target)
        return target

    @staticmethod
    def discard(staging: Path) -> None:
        """Remove a staged upload that will not become a job."""
        shutil.rmtree(staging, ignore_errors=True)

    def delete_job(self, job_id: str) -> None:
        """Remove every file of a job."""
        shutil.rmtree(self.job_dir(job_id), ignore_errors=True)

    def job_ids_on_disk(self) -> list[str]:
        """Job folders present (for finding files whose job record is gone)."""
        return sorted(p.name for p in (self.root / "jobs").iterdir() if _JOB_ID.match(p.name))
