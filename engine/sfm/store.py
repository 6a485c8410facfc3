"""Write an estimate into a scene folder: ``cameras.json`` (the one camera schema) and the
sparse points, so the folder loads like any uploaded scene."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from sparsesplat.engine.sfm.estimate import CameraEstimate
from sparsesplat.engine.sfm.points import write_sparse_points

CAMERAS_FILE = "cameras.json"
"""The scene folder's cameras file (the folder loader's marker)."""


def estimate_document(estimate: CameraEstimate, images: list[str] | None = None) -> dict[str, Any]:
    """The estimate as a ``cameras.json`` document; ``images`` renames the frames' images
    (paths relative to the scene folder of all the photos given, in their order; a frame is
    matched by its photo's file name, so photos left out simply have no frame)."""
    document = estimate.cameras.model_dump(mode="json", exclude_none=True)
    if images is not None:
        by_name = {Path(image).name: image for image in images}
        if len(by_name) != len(images):
            raise ValueError(f"two of the image paths share a file name: {images}")
        for frame in document["frames"]:
            if frame["image"] not in by_name:
                raise ValueError(f"no image path for the frame of {frame['image']}: {images}")
            frame["image"] = by_name[frame["image"]]
    return document


def write_estimate(estimate: CameraEstimate, path: Path, images: list[str] | None = None) -> Path:
    """Write the cameras file ``path`` (``cameras.json`` for a scene folder) and the sparse
    points beside it; returns ``path``. The points go first, so a folder with a cameras file
    always has its points."""
    write_sparse_points(path.parent, estimate.points, estimate.colours)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(estimate_document(estimate, images), indent=1))
    tmp.replace(path)
    return path
