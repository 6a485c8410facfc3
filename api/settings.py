"""The service's one typed settings object, read from ``SPARSESPLAT_*`` environment variables.

Every field can be set as ``SPARSESPLAT_<FIELD>`` (e.g. ``SPARSESPLAT_PORT=9000``) or in a
``.env`` file in the working directory. The defaults are the embedded setup: SQLite and local
files under ``./sparsesplat-data``, local worker processes, CPU, listening on 127.0.0.1.
"""

from __future__ import annotations

import json
import os
from enum import StrEnum
from pathlib import Path

from pydantic import Field, SecretStr, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

ENV_PREFIX = "SPARSESPLAT_"


def _default_models_dir() -> Path:
    """``$XDG_CACHE_HOME/sparsesplat/models`` (the engine looks in the same place)."""
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "sparsesplat" / "models"


class QueueBackend(StrEnum):
    """How jobs travel from the server to the workers."""

    local = "local"
    """Embedded: the job table itself is the queue; local worker processes lease jobs from it."""
    celery = "celery"
    """Scale-out: Celery over Redis (``broker_url``); job records in ``database_url``."""


class Device(StrEnum):
    """Where the trainer and the renderer run."""

    cpu = "cpu"
    """The default: the native CPU rasterizer."""
    cuda = "cuda"
    """A CUDA GPU through gsplat (install the ``cuda`` image or gsplat with --no-deps)."""
    auto = "auto"
    """CUDA when available, else CPU."""


class Settings(BaseSettings):
    """Service configuration. Field docs are the reference for each ``SPARSESPLAT_*`` variable."""

    model_config = SettingsConfigDict(
        env_prefix=ENV_PREFIX, env_file=".env", extra="ignore", validate_default=True
    )

    host: str = "127.0.0.1"
    """Interface the HTTP server binds to. Loopback by default; set 0.0.0.0 in containers."""
    port: int = Field(8000, ge=1, le=65535)
    """TCP port of the HTTP server."""
    data_dir: Path = Path("sparsesplat-data")
    """Root of local storage: uploads, models, renders, the SQLite database. With
    ``artifacts`` set, this machine's working copy of the job files (the bucket holds them)."""
    artifacts: str = ""
    """Where job files (uploads, checkpoints, models, exports) are kept for good: empty (the
    default) keeps them in ``data_dir`` alone, which workers on other machines must then
    mount; ``s3://BUCKET/PREFIX`` keeps them in an S3-API bucket (AWS S3, MinIO, Ceph, ...)
    shared by the API and every worker, which then share no folder (needs the ``s3``
    extra)."""
    s3_endpoint_url: str | None = None
    """Endpoint of an S3-compatible store (``http://minio:9000``); unset: AWS S3."""
    s3_region: str | None = None
    """Region of the bucket; unset: ``AWS_DEFAULT_REGION``, else ``us-east-1``."""
    s3_access_key_id: str | None = None
    """Access key of the bucket; unset: boto3's chain (``AWS_ACCESS_KEY_ID``, a profile, an
    instance role)."""
    s3_secret_access_key: SecretStr | None = None
    """Secret of ``s3_access_key_id``; unset: boto3's chain (``AWS_SECRET_ACCESS_KEY``, ...)."""
    database_url: str | None = None
    """SQLAlchemy-style URL of the job store. Default: ``sqlite:///<data_dir>/sparsesplat.db``.
    Use ``postgresql://user:pass@host/db`` for the distributed setup."""
    queue: QueueBackend = QueueBackend.local
    """Queue backend: ``local`` (embedded) or ``celery`` (Redis broker)."""
    broker_url: str = "redis://127.0.0.1:6379/0"
    """Celery broker URL; used only when ``queue=celery``."""
    device: Device = Device.cpu
    """Compute device for training and rendering."""
    workers: int = Field(1, ge=0, le=64)
    """Local worker processes the server starts (``queue=local``); 0: external workers only."""
    torch_threads: int = Field(2, ge=1, le=256)
    """Torch intra-op threads per worker process."""
    api_keys: list[SecretStr] = Field(default_factory=list)
    """Accepted API keys (``Authorization: Bearer <key>``); empty disables auth (loopback use)."""
    models_dir: Path = Field(default_factory=_default_models_dir)
    """Directory holding model weights (LPIPS VGG/AlexNet, optional MiDaS/DPT ONNX files)."""
    log_level: str = "INFO"
    """Logging level name (DEBUG, INFO, WARNING, ERROR)."""
    log_json: bool = True
    """One JSON object per log line (False: human-readable key=value lines)."""
    max_upload_mb: int = Field(512, ge=1)
    """Largest accepted request body (an upload), in MiB."""
    render_workers: int = Field(1, ge=0, le=64)
    """Local render worker processes the server starts; 0: external render workers only."""
    render_threads: int = Field(2, ge=1, le=256)
    """Torch intra-op threads per render worker."""
    train_nice: int = Field(10, ge=0, le=19)
    """Niceness a training worker process adds to itself when it starts, so that on shared
    cores the render workers (niceness 0) run first and renders stay interactive while a job
    trains; the job gets the cores whenever no render runs. 0: equal priority."""
    render_cache_models: int = Field(4, ge=1, le=1000)
    """Trained models each render worker keeps loaded (least recently used leave first)."""
    max_images: int = Field(64, ge=2, le=10_000)
    """Most images (training + held-out) in one job."""
    max_megapixels: float = Field(40.0, gt=0)
    """Largest accepted image, in millions of pixels (checked from the header, before decoding:
    a decompression bomb is refused without being decoded)."""
    max_render_megapixels: float = Field(16.0, gt=0)
    """Largest render, in millions of pixels per frame."""
    max_path_cameras: int = Field(240, ge=1)
    """Most cameras in one render path."""
    max_active_jobs_per_key: int = Field(10, ge=1)
    """Queued plus running jobs one API key may have."""
    renders_per_second: float = Field(20.0, gt=0)
    """Sustained renders per second per key (bursts up to twice this); 429 beyond."""
    lease_s: float = Field(30.0, gt=1)
    """How long a job's lease lasts without a heartbeat before it is presumed dead."""
    heartbeat_s: float = Field(5.0, gt=0)
    """Seconds between a worker's heartbeats (must be well below ``lease_s``)."""
    poll_s: float = Field(1.0, gt=0)
    """Seconds an idle training worker waits before asking for a job again."""
    cancel_grace_s: float = Field(30.0, gt=0)
    """Seconds a cancelled job gets to stop by itself before its worker process is ended."""
    checkpoint_interval_s: float = Field(120.0, gt=0)
    """Training seconds between a job's checkpoints: the most work a dead worker loses."""
    max_attempts: int = Field(3, ge=1)
    """Starts allowed for a job whose worker keeps dying, before it fails."""
    readiness_max_age_s: float = Field(30.0, gt=0)
    """``/readyz`` wants a worker heartbeat at most this old."""
    disk_reserve_mb: int = Field(64, ge=0)
    """Free space (MB) always left on the data folder's disk: a job starts only when its
    expected bytes fit above it, an upload is refused below it, and ``/healthz`` reports the
    disk ``full`` under it (``low`` under twice it)."""
    disk_wait_s: float = Field(600.0, ge=0)
    """How long the oldest queued job waits for disk space to start (the jobs behind it wait
    with it) before it fails, naming what it needs and what is free; while it waits, space
    freed by a DELETE, an expiry or an operator lets it start."""
    max_stored_mb_per_key: int = Field(0, ge=0)
    """Bytes (MB) one API key's jobs may hold on disk (uploads, checkpoints, models, exports):
    a submission over it is refused with 413. 0: no limit."""
    max_jobs_per_key: int = Field(0, ge=0)
    """Jobs one API key may keep stored, whatever their state (delete some to submit more):
    429 beyond. 0: no limit."""
    model_ttl_days: float = Field(0.0, ge=0)
    """Days a model (a succeeded job) is kept after it finished, unless pinned: then its files
    are removed and it answers 404 ``expired``. 0: models never expire."""
    sweep_interval_s: float = Field(60.0, gt=0)
    """Seconds between the server's sweeps for expired models and for files whose job record
    is gone."""

    @model_validator(mode="after")
    def _fill_database_url(self) -> Settings:
        if self.artifacts and not self.artifacts.startswith("s3://"):
            raise ValueError(
                f"artifacts: {self.artifacts!r} is not a location; leave it empty (files in "
                "data_dir) or write s3://BUCKET/PREFIX"
            )
        if self.artifacts.rstrip("/") == "s3:/" or self.artifacts.startswith("s3:///"):
            raise ValueError(f"artifacts: no bucket in {self.artifacts!r}: s3://BUCKET/PREFIX")
        if self.database_url is None:
            self.database_url = f"sqlite:///{self.data_dir / 'sparsesplat.db'}"
        if self.heartbeat_s * 2 >= self.lease_s:
            raise ValueError(
                f"heartbeat_s ({self.heartbeat_s}) must be under half of lease_s ({self.lease_s})"
            )
        return self

    def environment(self) -> dict[str, str]:
        """These settings as ``SPARSESPLAT_*`` variables, for child processes to read back."""
        out: dict[str, str] = {}
        for name, value in self.model_dump(mode="json").items():
            if name == "api_keys":
                value = [k.get_secret_value() for k in self.api_keys]
            elif name == "s3_secret_access_key" and self.s3_secret_access_key is not None:
                value = self.s3_secret_access_key.get_secret_value()
            if value is None:  # unset: the child reads the same default
                continue
            out[ENV_PREFIX + name.upper()] = value if isinstance(value, str) else json.dumps(value)
        return out

    @property
    def auth_enabled(self) -> bool:
        """Whether requests must carry an API key."""
        return bool(self.api_keys)


def load_settings(**overrides: object) -> Settings:
    """Read settings from the environment (and ``.env``), with explicit keyword overrides on top."""
    return Settings(**overrides)  # type: ignore[arg-type]
