"""Wire schemas of training jobs: what a client submits, what it reads back, and the events.

A job trains one uploaded scene. When it succeeds it has a model with the same id, which the
render and export routes serve (``/v1/models/{job_id}/...``).
"""

from __future__ import annotations

from datetime import datetime
from enum import StrEnum
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from sparsesplat.api.camera_estimation import CameraEstimation
from sparsesplat.api.names import TERMINAL_JOB_STATES, ColorModelName, InitName, PresetName


class JobState(StrEnum):
    """Life cycle of a job. ``queued`` → ``running`` → one of the three terminal states."""

    queued = "queued"
    """Waiting for a worker (also after a worker died: the job resumes from its checkpoint)."""
    running = "running"
    """A worker holds the job's lease and trains it."""
    succeeded = "succeeded"
    """Trained; the model can be rendered and exported."""
    failed = "failed"
    """Gave up; ``error`` says why and what to change."""
    cancelled = "cancelled"
    """Cancelled by its owner."""

    @property
    def terminal(self) -> bool:
        """Whether the job will not change state again."""
        return self.value in TERMINAL_JOB_STATES


class JobSpec(BaseModel):
    """How to train: the JSON ``spec`` part of ``POST /v1/jobs``. Every field is optional."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [{"preset": "llff", "depth_prior": "pydnet", "seed": 0, "iterations": 2000}]
        },
    )

    preset: PresetName | None = None
    """Training recipe; None picks one from the scene (background and camera layout)."""
    depth_prior: str | None = None
    """Depth prior: ``pydnet`` (bundled), ``plane_sweep``, ``user`` (the depth maps sent
    with the images; ``uploaded`` is its deprecated spelling), ``none``, or ``onnx:NAME`` for a
    MiDaS/DPT ONNX file in the server's models directory. None: the preset's."""
    color_model: ColorModelName | None = None
    """Colour model; None: the preset's (neural)."""
    hard_depth: bool | None = None
    """Hard-depth pass (moves only centres); None: the preset's."""
    soft_depth: bool | None = None
    """Soft-depth pass (moves only opacities); None: the preset's."""
    seed: int = Field(default=0, ge=0, le=2**31 - 1)
    """Random seed of the run."""
    iterations: int | None = Field(default=None, ge=1, le=100_000)
    """Iterations to train; None: the preset's default length for the scene's camera layout
    (``sparsesplat train --help`` lists them). The preset's 6000-iteration reference schedule
    is compressed to the length asked for."""
    time_budget_s: float | None = Field(default=None, gt=0, le=7 * 24 * 3600)
    """Train until this many training seconds are spent instead of for ``iterations`` (a
    deadline): the preset's schedule (learning-rate decay, densification, depth starts) follows
    the elapsed fraction of the budget."""
    eval_interval_s: float | None = Field(default=None, gt=0, le=24 * 3600)
    """Training seconds between held-out error records (the error-against-time curve);
    None: the preset's (60 s). ``record_interval_s`` is its deprecated spelling."""
    background: tuple[float, float, float] | None = None
    """Background colour (RGB in [0, 1]) for targets and renders; None: from the scene."""
    init: InitName | None = None
    """Initial Gaussians (``random``, ``dense``, ``sparse``: the points triangulated when
    the cameras were estimated from the photos, or ``auto``: ``dense`` for forward-facing
    cameras, ``random`` for an orbit); None: the preset's."""
    dropout: bool | None = None
    """DropGaussian: drop a random share of Gaussians in each photometric pass, compensating
    the rest's opacity (a prior-free sparse-view regulariser); None: the preset's."""
    dtu_background: bool | None = None
    """The DTU reference pieces for an object on a dark background (dark-pixel mask, black
    targets there, background-alpha pass, black/white densification rule); None: the
    preset's."""
    consistency_weight: float | None = Field(default=None, ge=0, le=10)
    """Weight of the multi-view warp-consistency term (0: off); None: the preset's."""
    depth_min_agreement: float | None = Field(default=None, ge=-1, le=1)
    """Skip the depth prior on training views whose depth ranks pixels unlike the photos' own
    multi-view geometry (Spearman rank correlation with a plane sweep below this; 0.3 is a
    sensible value); None: the preset's (every view keeps its prior)."""
    near_prune: bool | None = None
    """Delete Gaussians within half the scene's near bound of its render path (LLFF: the
    spiral through every pose) in training, and leave those near a held-out camera out of
    its evaluation; None: the preset's."""
    overrides: dict[str, Any] | None = None
    """Any other training setting by its dotted name (as ``sparsesplat train --set``), e.g.
    ``{"depth.soft_start": 500, "photometric.lambda_dssim": 0.3}``; applied after the fields
    above and checked by the trainer when the job starts (a bad name or value fails the job
    with the field named)."""

    @model_validator(mode="before")
    @classmethod
    def _deprecated_spellings(cls, data: Any) -> Any:
        # Stored jobs and older clients use the names of earlier versions.
        if not isinstance(data, dict):
            return data
        data = dict(data)
        old = data.pop("record_interval_s", None)
        if old is not None:
            if data.get("eval_interval_s") is not None:
                raise ValueError("give either 'eval_interval_s' or 'record_interval_s', not both")
            data["eval_interval_s"] = old
        if data.get("depth_prior") == "uploaded":
            data["depth_prior"] = "user"
        return data

    @model_validator(mode="after")
    def _one_length(self) -> JobSpec:
        if self.iterations is not None and self.time_budget_s is not None:
            raise ValueError("give either 'iterations' or 'time_budget_s', not both")
        if self.background is not None and not all(0.0 <= c <= 1.0 for c in self.background):
            raise ValueError("background: each channel must be in [0, 1]")
        return self


class Record(BaseModel):
    """One point of the error-against-run-time curve (held-out views)."""

    iteration: int
    """Iterations completed."""
    elapsed_s: float
    """Training seconds so far (evaluation and checkpoint time excluded)."""
    train_loss: float | None = None
    """Mean photometric training loss since the previous record."""
    psnr: float | None = None
    """Mean held-out PSNR in dB (None without held-out views)."""
    ssim: float | None = None
    """Mean held-out SSIM."""
    lpips: float | None = None
    """Mean held-out LPIPS (VGG; None when its weights are not installed)."""
    avge: float | None = None
    """Geometric mean of the three errors (None without LPIPS)."""
    n_gaussians: int
    """Gaussians in the model at this point."""
    final: bool = False
    """True for the record taken at the end (all held-out views)."""
    views: int = 0
    """Held-out views the record scored. Interim records score the same few each time
    (``record.eval_max_views``); where that is fewer than all, the end brings a record on
    those few (the curve's last point) and then the final one on all of them."""


class Progress(BaseModel):
    """Where a running job is."""

    iteration: int = 0
    """Iterations completed."""
    total: int | None = None
    """Iterations the run will do."""
    elapsed_s: float = 0.0
    """Training seconds so far."""
    eta_s: float | None = None
    """Estimated training seconds remaining."""
    phase: str | None = None
    """What the worker does now: ``preparing``, ``training``, ``evaluating``, ``exporting``…"""
    last_record: Record | None = None
    """The latest held-out record."""
    preset: str | None = None
    """The recipe in use (chosen from the scene when the spec named none)."""
    preset_reason: str | None = None
    """Why that recipe, when it was chosen from the scene."""
    cameras: CameraEstimation | None = None
    """For photos uploaded without cameras: how they were estimated, once done."""


class Job(BaseModel):
    """A job as ``GET /v1/jobs/{id}`` returns it."""

    id: str
    """Job id (also the id of its model)."""
    state: JobState
    """Current state."""
    spec: JobSpec
    """What was asked for."""
    created_at: datetime
    """Submission time (UTC)."""
    started_at: datetime | None = None
    """When a worker first started it."""
    finished_at: datetime | None = None
    """When it reached a terminal state."""
    queue_position: int | None = None
    """Jobs ahead of it in the queue (0: next); only while queued."""
    progress: Progress | None = None
    """Only once a worker has started it."""
    error: str | None = None
    """Why it failed, in words a user can act on."""
    attempts: int = 0
    """Times a worker has started it (a worker that died counts)."""
    n_train_views: int
    """Training images uploaded."""
    n_test_views: int
    """Held-out images uploaded (scored against renders while training)."""
    has_model: bool = False
    """Whether ``/v1/models/{id}`` can render and export."""
    disk_bytes: int | None = None
    """Bytes the job keeps on disk (upload, stored model, exports, metrics), once it has
    succeeded; None before."""
    warnings: list[str] = Field(default_factory=list)
    """What training found wrong that the upload could not show (e.g. held-out renders that
    stay empty, or a model no better than a constant image: usually poses read the wrong way).
    A job can succeed with warnings; each one is also a ``warning`` event."""
    pinned: bool = False
    """Whether its model is kept past the service's model expiry (``PUT /v1/models/{id}/pin``)."""
    expires_at: datetime | None = None
    """When its model expires (a succeeded, unpinned job on a service with a model expiry)."""
    expired: bool = False
    """Whether its model has expired: its files are gone and its model answers 404."""


class JobPage(BaseModel):
    """One page of ``GET /v1/jobs``, newest first."""

    jobs: list[Job]
    """The jobs on this page."""
    next_cursor: str | None = None
    """Pass as ``cursor`` for the next page; None on the last page."""


EventType = Literal["state", "progress", "record", "warning"]
"""``state``: the job changed state; ``progress``: iteration/phase update; ``record``: a
held-out error record; ``warning``: something training found wrong (``{message}``, also in
the job's ``warnings``)."""


class Event(BaseModel):
    """One stored event of a job; ``seq`` numbers them 1, 2, 3… per job, without gaps."""

    seq: int
    """Sequence number within the job (reconnect with ``?after=seq``)."""
    job_id: str
    """The job."""
    type: EventType
    """What kind of event."""
    time: datetime
    """When it was stored (UTC)."""
    data: dict[str, Any]
    """``state``: {state, message}; ``progress``: a Progress; ``record``: a Record;
    ``warning``: {message}."""


class ModelInfo(BaseModel):
    """A trained model (``GET /v1/models/{id}``)."""

    id: str
    """Model id (= the job id)."""
    n_gaussians: int
    """Gaussians in the model."""
    iterations: int
    """Iterations it was trained for."""
    metrics: dict[str, float | None]
    """Final held-out metrics (psnr, ssim, lpips, avge), the training ``seconds`` used and,
    for a job with a time budget, ``time_budget_s`` (budget against used), or for a job of
    the preset's default length, ``time_limit_s`` (the most it may train; a job the limit
    ended early also has a warning saying so)."""
    exports: list[str]
    """Available export formats (``ply``, ``splat``, ``checkpoint``)."""
    cameras: list[dict[str, Any]]
    """The uploaded cameras (as in ``cameras.json``, with their split), or those estimated
    from photos uploaded without them (OpenCV camera-to-world, the frame the model was
    trained in); where training refined the poses (estimated cameras uncertain by 0.6° or
    more), the training frames' poses as refined, the frame the model is in. The i-th one's
    image is ``GET /v1/jobs/{id}/images/{i}``."""
    background: tuple[float, float, float] | None = None
    """Background colour (RGB in [0, 1]) the model was trained and renders with."""
    disk_bytes: int | None = None
    """Bytes the job keeps on disk (upload, stored model, exports, metrics)."""
    depth_priors: int = 0
    """Training views whose depth prior ``GET /v1/jobs/{id}/priors/{k}`` serves as a picture
    (k = 0 .. depth_priors - 1; 0 when the job used no prior)."""
    pinned: bool = False
    """Whether it is kept past the service's model expiry."""
    expires_at: datetime | None = None
    """When it expires (None: pinned, or the service keeps models for good)."""
