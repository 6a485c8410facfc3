"""What a job will write to disk: its expected bytes before it starts, and the size of what it
is about to write when a write fails.

The figures per Gaussian and for the neural colour field were measured on the smoke mic upload
(``docs/service.md``, "Disk space"); a checkpoint is a ``torch.save`` zip of float32 tensors, so
its size is its tensors' bytes plus a few kB of framing.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from sparsesplat.api.jobs import JobSpec
from sparsesplat.worker.run_spec import run_spec

log = logging.getLogger("sparsesplat.worker")

TRAINING_BYTES_PER_GAUSSIAN = {"neural": 140, "sh": 716}
"""Bytes per Gaussian of a training checkpoint: its 11 float32 parameters (centre, scale,
rotation, opacity; with SH colour also 48 SH coefficients), Adam's two moments of each, and
the two densification accumulators."""
MODEL_BYTES_PER_GAUSSIAN = {"neural": 44, "sh": 236}
"""Bytes per Gaussian of a finished model (parameters only)."""
EXPORT_BYTES_PER_GAUSSIAN = 248 + 32
"""``model.ply`` (62 float32 per Gaussian: degree-3 SH) plus ``model.splat`` (32 bytes)."""
NEURAL_FIELD_TRAINING_BYTES = 147_100_000
"""The neural colour field in a training checkpoint at ``color.hash_log2_size`` 19: 49 MB of
hash tables and MLPs and 98 MB of Adam's two moments of them; it scales with the table size."""
NEURAL_FIELD_MODEL_BYTES = 24_550_000
"""The same field in a finished model (tables at half precision, no optimizer state)."""
PRIOR_BYTES_PER_PIXEL = 8
"""A cached depth prior: depth and confidence as float32 per training pixel (stored
compressed: a bound)."""
SMALL_FILES_BYTES = 2_000_000
"""Metrics, series, plot and depth-prior pictures: a bound."""
DOUBLINGS_PER_DENSIFICATION = 1
"""A densification step clones or splits each Gaussian at most once: it at most doubles them."""


def expected_gaussians(config: Any) -> int:
    """The most Gaussians a run of ``config`` can reach: its initial points doubled at each
    densification step its length holds, under the cap (the cap alone under a time budget)."""
    init, densify = config.init, config.densify
    start = max(init.points or init.points_max, init.dense_points or 0)
    cap = densify.max_gaussians or 10 * start
    if config.time_budget_s is not None:
        return int(cap)
    iterations = int(config.iterations)
    scale = 6000 / max(iterations, 1)  # the reference schedule's positions, compressed
    steps = sum(
        1
        for it in range(densify.interval, iterations + 1, densify.interval)
        if densify.start < it * scale < densify.until
    )
    return int(min(cap, start * 2 ** min(steps * DOUBLINGS_PER_DENSIFICATION, 40)))


def checkpoint_bytes(color_model: str, n_gaussians: int, hash_log2_size: int = 19) -> int:
    """Bytes of a training checkpoint of ``n_gaussians`` with ``color_model``."""
    per = TRAINING_BYTES_PER_GAUSSIAN.get(color_model, max(TRAINING_BYTES_PER_GAUSSIAN.values()))
    field = _field_bytes(NEURAL_FIELD_TRAINING_BYTES, color_model, hash_log2_size)
    return field + per * n_gaussians


def model_bytes(color_model: str, n_gaussians: int, hash_log2_size: int = 19) -> int:
    """Bytes of a finished model (``checkpoint.pt`` of a succeeded job)."""
    per = MODEL_BYTES_PER_GAUSSIAN.get(color_model, max(MODEL_BYTES_PER_GAUSSIAN.values()))
    field = _field_bytes(NEURAL_FIELD_MODEL_BYTES, color_model, hash_log2_size)
    return field + per * n_gaussians


def _field_bytes(at_19: int, color_model: str, hash_log2_size: int) -> int:
    if color_model != "neural":
        return 0
    return int(at_19 * 2 ** min(hash_log2_size - 19, 4))


def config_bytes(config: Any, train_pixels: int = 0) -> int:
    """Peak bytes a run of ``config`` holds in its run folder: two training checkpoints while
    one replaces the other, or at the end the checkpoint, the exports and the model written
    beside it, whichever is more; plus the small files and, for a run with a depth prior, its
    cached priors (``train_pixels``: the training images' pixels)."""
    n = expected_gaussians(config)
    color, log2 = config.color.model, config.color.hash_log2_size
    checkpoint = checkpoint_bytes(color, n, log2)
    final = checkpoint + EXPORT_BYTES_PER_GAUSSIAN * n + model_bytes(color, n, log2)
    priors = PRIOR_BYTES_PER_PIXEL * train_pixels if config.uses_depth else 0
    return max(2 * checkpoint, final) + priors + SMALL_FILES_BYTES


def train_pixels(upload_dir: Path) -> int:
    """Pixels of the upload's training images (read from their headers); every image of a
    photos-only upload."""
    import json

    from PIL import Image

    cameras = upload_dir / "cameras.json"
    if cameras.is_file():
        frames = json.loads(cameras.read_text())["frames"]
        paths = [upload_dir / f["image"] for f in frames if f.get("split", "train") == "train"]
    else:
        paths = sorted((upload_dir / "images").glob("*"))
    total = 0
    for path in paths:
        try:
            with Image.open(path) as image:
                total += image.width * image.height
        except OSError:  # the job reports an unreadable image itself
            continue
    return total


def expected_job_bytes(spec: JobSpec, upload_dir: Path) -> int:
    """Bytes the job of ``spec`` is expected to write (its upload is stored already). The
    preset is the one the job would choose from its scene; when the scene cannot be read yet
    (photos whose cameras are still to estimate) the largest of the presets."""
    from sparsesplat.engine.errors import EngineError
    from sparsesplat.engine.train.config.presets import PRESETS
    from sparsesplat.engine.train.run import plan_run

    scene = None
    if spec.preset is None:
        try:
            from sparsesplat.engine.datasets import load_scene

            scene = load_scene(upload_dir, format="folder")
        except (EngineError, OSError, ValueError):
            scene = None
    specs = [spec] if spec.preset is not None or scene is not None else [
        spec.model_copy(update={"preset": name}) for name in PRESETS
    ]  # fmt: skip
    pixels = train_pixels(upload_dir)
    estimates = []
    for candidate in specs:
        try:
            estimates.append(config_bytes(plan_run(run_spec(candidate), scene).config, pixels))
        except (EngineError, ValueError):  # the job itself reports a bad spec when it runs
            continue
    return max(estimates, default=SMALL_FILES_BYTES)


def tensor_bytes(obj: Any) -> int:
    """Bytes of the tensors in a (nested) state dict: what ``torch.save`` of it writes, give
    or take its framing."""
    import torch

    if isinstance(obj, torch.Tensor):
        return int(obj.numel() * obj.element_size())
    if isinstance(obj, dict):
        return sum(tensor_bytes(v) for v in obj.values())
    if isinstance(obj, list | tuple):
        return sum(tensor_bytes(v) for v in obj)
    return 0
