"""Scene loading: every supported on-disk format with the paper's train/test split.

``load_scene(path, views=None, format=None, downscale=1)`` auto-detects the format:
``llff`` (poses_bounds.npy), ``blender`` (transforms_train.json), ``dtu``
(cameras_sphere.npz), ``ngp`` (transforms.json), ``folder`` (cameras.json, the API upload).
"""

from __future__ import annotations

from pathlib import Path

from sparsesplat.api.scenes import formats as scene_formats
from sparsesplat.api.scenes.formats import FORMATS, MARKERS, PAPER_VIEWS
from sparsesplat.engine.datasets.blender import load_blender
from sparsesplat.engine.datasets.common import check_downscale
from sparsesplat.engine.datasets.dtu import load_dtu
from sparsesplat.engine.datasets.folder import load_folder
from sparsesplat.engine.datasets.llff import load_llff
from sparsesplat.engine.datasets.ngp import load_ngp
from sparsesplat.engine.errors import SceneError, reraise_as
from sparsesplat.engine.scene import Scene

detect_format = reraise_as(SceneError)(scene_formats.detect_format)
"""The format of a scene folder, from its marker file (SceneError when none matches)."""


def load_scene(
    path: str | Path,
    views: int | None = None,
    format: str | None = None,
    downscale: int = 1,
) -> Scene:
    """Load the scene at ``path`` with the paper's split.

    Args:
        path: scene folder.
        views: number of training views; None = the paper's (3 LLFF/DTU/ngp, 8 Blender; all
            training frames for an upload folder).
        format: one of :data:`FORMATS`; None detects it from the marker files.
        downscale: extra integer shrink factor on top of the stored images (1 = as stored,
            which is the paper's resolution for every scene in shared/data).
    """
    root = Path(path)
    with reraise_as(SceneError):
        fmt = scene_formats.check_format(format, str(root)) if format else detect_format(root)
    if not root.is_dir():
        raise SceneError(f"{root}: scene folder not found")
    downscale = check_downscale(downscale, str(root))
    if fmt == "folder":
        return load_folder(root, views, downscale)
    count = PAPER_VIEWS[fmt] if views is None else views
    loader = {"llff": load_llff, "blender": load_blender, "dtu": load_dtu, "ngp": load_ngp}[fmt]
    return loader(root, count, downscale)


def source_image_count(path: str | Path, format: str | None = None) -> int:
    """How many posed images the scene folder holds in all (before the split)."""
    import json

    from sparsesplat.api.scenes.dtu import image_folder
    from sparsesplat.engine.datasets.llff import find_image_dir
    from sparsesplat.engine.images import list_images

    root = Path(path)
    fmt = format or detect_format(root)
    try:
        if fmt == "llff":
            return len(list_images(find_image_dir(root)))
        if fmt == "dtu":
            return len(list_images(image_folder(root)))
        if fmt == "blender":
            return sum(
                len(json.loads((root / f"transforms_{s}.json").read_text())["frames"])
                for s in ("train", "val", "test")
                if (root / f"transforms_{s}.json").is_file()
            )
        name = "cameras.json" if fmt == "folder" else "transforms.json"
        return len(json.loads((root / name).read_text())["frames"])
    except (OSError, ValueError, KeyError) as exc:
        raise SceneError(f"{root}: cannot count images ({exc})") from exc


__all__ = [
    "FORMATS",
    "MARKERS",
    "PAPER_VIEWS",
    "detect_format",
    "load_scene",
    "source_image_count",
]
