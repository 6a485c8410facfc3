"""Names shared by every package: job states, training choices, artifact files, suffixes.

Standard library only, so each side of the torch line (the engine, the torch-free SDK, the
server) takes these from here instead of spelling them again. The engine's own config
validates against the same literals (``tests/foundation/test_shared_names.py`` pins them).
"""

from __future__ import annotations

from typing import Literal

PresetName = Literal["llff", "dtu", "blender", "object", "default"]
"""Training recipes (engine presets): ``llff`` forward-facing captures, ``dtu`` object on a
dark background, ``blender`` synthetic object on white, ``object`` an object photographed with
alpha (inward-looking cameras), ``default`` user uploads (LLFF recipe)."""

ColorModelName = Literal["neural", "sh"]
"""Colour model: DNGaussian's neural colour field, or per-Gaussian spherical harmonics."""

InitName = Literal["random", "dense", "sparse", "auto"]
"""Initial Gaussians: ``random`` points in a box around the cameras' view (the method's),
``dense`` points back-projected from the confident pixels of a plane-sweep depth of the
uploaded views themselves, ``sparse`` the points of the camera estimation (photos uploaded
without cameras), or ``auto``: ``dense`` when the cameras face forward, ``random`` when they
look inward."""

TERMINAL_JOB_STATES: frozenset[str] = frozenset({"succeeded", "failed", "cancelled"})
"""Job states a job never leaves (``api.jobs.JobState`` values)."""

ARTIFACT_FILES: dict[str, str] = {
    "checkpoint": "checkpoint.pt",
    "ply": "model.ply",
    "splat": "model.splat",
    "metrics": "metrics.json",
    "series_json": "metrics_series.json",
    "series_csv": "metrics_series.csv",
    "series_png": "metrics_series.png",
}
"""Artifact kind -> file name inside a training run's folder (the trainer writes these, the
service stores and serves them under the same names)."""

ExportFormat = Literal["ply", "splat", "checkpoint"]
"""A trained model's downloadable forms (each the artifact of the same kind)."""

EXPORT_SUFFIXES: dict[str, str] = {"ply": ".ply", "splat": ".splat", "checkpoint": ".pt"}
"""Export format -> file suffix of its download (the suffix of its artifact file)."""

ImageFormat = Literal["png", "jpeg", "webp"]
"""Encodings of a rendered colour image."""

IMAGE_OUTPUT_SUFFIXES: dict[str, ImageFormat] = {
    ".png": "png",
    ".jpg": "jpeg",
    ".jpeg": "jpeg",
    ".webp": "webp",
}
"""Output file suffix -> the colour image format it is written in (render outputs)."""

VIDEO_SUFFIXES = (".mp4", ".gif", ".webm", ".mov", ".mkv")
"""Output suffixes written as a video of a camera path."""
